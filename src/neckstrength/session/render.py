"""Text screens of the clinician session (the terminal front end's view of :class:`~neckstrength.session.Session`)
===========================================================================================================

Every function here turns the session's numbers into text and returns it; nothing here prints, reads input or
changes the session. The numbers come from the engine's methods (the same ones :meth:`Session.snapshot` reports), so
the terminal and any other front end show the same values.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

HELP = """Commands:
  <force>                          force in N for the proposed direction, e.g. 142 or 142 N
  <force> act=MUSCLE:VALUE,...     the same with EMG activations in [0, 1], e.g. 142 act=TS-B:0.4,TS-E:0.7
  measure <direction> <force> [act=MUSCLE:VALUE,...]   a force for another (untested) direction
  measure <posture>:<direction> <force> [act=...]      sessions with --postures: a test in that posture, e.g.
                                   measure flex20:back 183 (a bare direction is taken in the proposed posture)
  skip                             do not test the proposed direction now (it is proposed no more)
  undo                             remove the last measurement or skip
  stop                             finish: write summary.csv and summary.png
  help                             this text
Forces are in newtons, 0 < F <= {max:g} N. Ctrl-D pauses (resume with `neckstrength session resume --out DIR`)."""


MIN_MC_CLUSTERS = 10     # below this effective number of independent draws the Monte Carlo error is not shown


def bar_chart(labels: Sequence[str], values: Sequence[float], width: int = 30, mark: str | None = None,
              marks: Mapping[str, str] | None = None) -> str:
    """Compact horizontal text bars (Fig. 6.8 as text): one line per label, scaled to the largest value."""
    vals = np.asarray(values, float)
    top = max(float(np.nanmax(vals)), 1e-12) if len(vals) else 1.0
    lw = max((len(x) for x in labels), default=0)
    lines = []
    blocks = " ▏▎▍▌▋▊▉█"
    for lab, v in zip(labels, vals):
        x = max(v, 0.0) / top * width
        full = int(x)
        part = blocks[int(round((x - full) * 8))] if full < width else ""
        bar = ("█" * full + part.strip()).ljust(width)
        note = (marks or {}).get(lab, "")
        if lab == mark:
            note = ("<- proposed " + note).strip()
        lines.append(f"  {lab:<{lw}} {bar} {v:7.3f}  {note}".rstrip())
    return "\n".join(lines)


def _normal_words(n: np.ndarray) -> str:
    words = []
    for comp, pos, neg in ((n[0], "forward", "backward"), (n[1], "up", "down"), (n[2], "to the right", "to the left")):
        if abs(comp) >= 0.3:
            words.append(pos if comp > 0 else neg)
    return " and ".join(words) or "along the normal"


def where_to_push(directions: pd.DataFrame, spec_csv: str | Path | None) -> dict[str, str]:
    """Direction name -> where the pad sits on the head and which way the head pushes (outward normal)."""
    spec = {}
    if spec_csv and Path(spec_csv).exists():
        s = pd.read_csv(spec_csv, comment="#")
        spec = {r["name"]: (r.get("mirror_of"), r.get("rationale")) for r in s.to_dict("records")}
    out = {}
    for r in directions.to_dict("records"):
        name = r["name"]
        mirror, why = spec.get(name, (None, None))
        if isinstance(mirror, str) and mirror:
            why = spec.get(mirror, (None, ""))[1]
            why = f"as {mirror} on the left side: {why}" if isinstance(why, str) else f"mirror of {mirror}"
        n = np.array([r["nx"], r["ny"], r["nz"]], float)
        side = f"point ({r['px']:.3f}, {r['py']:.3f}, {r['pz']:.3f}) m in the skull frame"
        where = why if isinstance(why, str) and why else side
        out[name] = f"{where}; the head pushes {_normal_words(n)} against the pad"
    return out


def screen(session) -> str:
    """The screen of the current step: the proposed test and where to push, the expected information of every
    remaining test (a text bar chart like Fig. 6.8), the estimate with its label, P(deficit) or the decision, and the
    stop recommendation."""
    p = session.proposal()
    prop = session.choice(p)
    n_t = len(session.state.tested)
    what = "tests (posture:direction)" if session.postures else "directions"
    lines = [f"=== step {n_t + 1} · participant {session.opts.participant} · model {session.model.name} · "
             f"{n_t} of {len(session.directions)} {what} tested"
             + (f" ({', '.join(session.state.tested)})" if n_t else "") + " ==="]
    if prop is not None and session.postures:
        post, dname = session.split(prop)
        now = session.state.post.current_posture
        change = f"; posture change from {now}" if post != now else ""
        cost = (f", charged {session.opts.posture_change_cost:g} nats" if change and session.opts.posture_change_cost
                else "")
        lines.append(f"Proposed: posture {post} / direction {dname}{change}{cost}  -- {session.push.get(dname, '')}")
    elif prop is not None:
        lines.append(f"Proposed: {prop}  -- {session.push.get(prop, '')}")
    if p is not None:
        t = p.table()
        g = "Eq. 6.8 with priorities" if session.gamma is not None else "Eq. 6.7, mean over muscles"
        if session.criterion == "joint_eig":
            lines.append("Expected information gain about the joint strengths of each remaining direction "
                         "(joint posterior; nats):")
        elif session.criterion == "marginal_entropy":
            lines.append(f"Expected entropy reduction of each remaining direction (Eq. 6.6 on the joint "
                         f"posterior; score {g}; nats):")
        else:
            lines.append(f"Expected entropy reduction of each remaining direction (Eq. 6.6; score {g}; nats):")
        marks = {d: "(skipped)" for d in session.skipped}
        cost = session.opts.posture_change_cost
        if session.postures and cost > 0:        # the bars are gain - cost for a pair in another posture
            lines[-1] = lines[-1][:-1] + f"; minus {cost:g} nats for a posture change):"
            now = session.state.post.current_posture
            for d, v in zip(t["direction"], t["score"]):
                if session.split(d)[0] != now:
                    marks[d] = (marks.get(d, "") + f" (gain {v + cost:.3f} - {cost:g} posture change)").strip()
        order = session.ranked(p)
        lines.append(bar_chart(list(order["direction"]), list(order["score"]), mark=prop, marks=marks))
    e = session.estimate()
    lines.append("Current estimate (posterior mean ± sd, N; prior in brackets). " + session.uncertainty_label() + ":")
    lw = max(len(m) for m in session.muscles)
    for r in e.to_dict("records"):
        lines.append(f"  {r['muscle']:<{lw}} {r['f_c']:8.1f} ± {r['sd_c']:6.1f}   "
                     f"[{r['f_0']:7.1f} ± {r['sd_0']:6.1f}]")
    lines.extend(deficit_lines(session))
    lines.append(session.recommendation(p)[1])
    return "\n".join(lines)


def decision_lines(session) -> list[str]:
    """The deficit decision in a clinician's words, with what it depends on (issue 31)."""
    dec = session.decision
    s = dec.settings
    h = dec.history[-1]
    tr = [x["p_deficit"] for x in dec.history]
    arrows = ("... -> " if len(tr) > 8 else "") + " -> ".join(f"{x:.2f}" for x in tr[-8:])
    word = {"deficit": "DEFICIT", "no deficit": "NO DEFICIT", "undecided": "UNDECIDED",
            "model misfit": "NOT DECIDABLE (the model does not fit these forces)"}[h["decision"]]
    lo, hi = s.deficit_range
    bf = h["log_bf"]
    bft = f"{np.exp(bf):.3g}" if abs(bf) < 50 else ("> 1e21" if bf > 0 else "< 1e-21")
    return [
        f"Deep neck extensors ({'+'.join(s.group)}, both sides) weak? {word}: P(deficit) = {h['p_deficit']:.2f} "
        f"(decided at >= {s.p_decide:.2f} or <= {1 - s.p_decide:.2f})   trend: {arrows}",
        f"  Bayes factor deficit : normal = {bft} (log {bf:+.1f} ± {h['log_bf_se']:.1f}, Monte Carlo error, "
        f"heuristic); prior prevalence {s.prevalence:.0%} (clinician.decision.prevalence)",
        f"  depends on: deficit = each side at {lo:.0%}-{hi:.0%} of normal (uniform), normal = at least "
        f"{hi:.0%}; every muscle varies with sd {s.population_sd:.0%}; noise {s.noise:.0%} ({s.noise_source}); "
        f"{s.n_candidates} candidates per hypothesis",
        f"  {misfit_text(h, s)}",
    ] + ([f"  WARNING: no strength vector of the model fits these forces better than {h['misfit_rms']:.1%} RMS, "
          f"above the guard's threshold {h.get('misfit_threshold', float('nan')):.1%}: the Bayes factor then says "
          f"which hypothesis misfits less, not whether the muscle is weak (docs/clinician.md; the gap diagnosis "
          f"says where the model misses)"] if h["decision"] == "model misfit" else []) + [decision_p_label(dec)]


def misfit_text(h: dict, s) -> str:
    """The misfit guard's line of a decision history row (calibrated or heuristic, with its threshold); rows of an
    older log without the guard's fields get the heuristic rule's wording."""
    if h.get("misfit_label"):
        return str(h["misfit_label"])
    rms = h.get("misfit_rms", float("nan"))
    return (f"misfit guard: best fit {rms:.1%} RMS; heuristic ({s.misfit_factor:g} x the {s.noise:.0%} noise)"
            if np.isfinite(rms) else "misfit guard: not checked yet")


def decision_p_label(dec) -> str:
    """What the printed P(deficit) is: recalibrated on simulated patients (with its held-out check) where the
    shipped recalibration holds, else the model's own probability, labelled heuristic with the reason."""
    if dec.calibrated:
        return (f"  P(deficit) {dec.p_label()} (docs/clinician.md); it holds for patients like the simulated ones "
                f"(5% noise, the cohort's population), not under model misfit, which real participants have")
    return (f"  P(deficit) is NOT calibrated: {dec.p_label()}. On simulated patients of this model the model's own "
            f"P was conservative between 0.2 and 0.6; the rule's sensitivity and false alarms are measured there "
            f"(docs/clinician.md, decision study); not checked under model misfit")


def deficit_lines(session) -> list[str]:
    """P(deficit) of the configured group with its trend and label; the decision's lines when the session has one."""
    if getattr(session, "decision", None) is not None:
        return decision_lines(session)
    tr = session.deficit_trend()
    if not tr:
        return []
    arrows = " -> ".join(f"{x:.2f}" for x in tr[-8:])
    more = "... -> " if len(tr) > 8 else ""
    how = (f"joint posterior, {session.settings.n_candidates} candidates" if session.joint
           else "thesis scheme, the group's muscles taken as independent")
    se = ""
    if session.joint:
        h = session.state.history[-1]
        e, k = h.get("p_deficit_se", float("nan")), h.get("mc_clusters", float("nan"))
        se = f" ± {e:.2f} (Monte Carlo error, 1 se)" if np.isfinite(e) else ""
        if se and k < MIN_MC_CLUSTERS:
            se = (f" ± ? (Monte Carlo error unknown: the candidates descend from about {k:.0f} independent "
                  "draws; the sampler has collapsed, do not trust this value)")
    out = [f"P(deep-extensor deficit: {session.deficit.label()}) = {tr[-1]:.2f}{se}   trend (prior -> now): "
           f"{more}{arrows}",
           f"  ({how}. NOT a calibrated probability: checked only on simulated participants of this model "
           f"(how often it finds a deficit: docs/clinician.md), never under model misfit)"]
    if se:
        out.append("  (the ± is the Monte Carlo error of the candidates, from their genealogy; heuristic: "
                   "independent candidate sets differed by 0.9-2 times it in the benchmark, docs/clinician.md)")
    return out


def prompt(session) -> str:
    """The prompt: the proposed test, or the commands when none is proposed."""
    prop = session.choice(session.proposal())
    return f"force (N) for {prop}, or a command [help]> " if prop else "command (measure/undo/stop/help)> "


def final_table(session) -> str:
    """The final estimate (prior, posterior mean and sd, entropy per muscle) as printed at stop."""
    e = session.estimate()
    cols = ["muscle", "f_0", "f_c", "sd_c", "entropy"]
    return ("Final estimate (" + (", ".join(session.state.tested) or "no measurements") + "):\n"
            + e[cols].to_string(index=False, float_format=lambda v: f"{v:.1f}"))


def proposed_text(session, label: str | None) -> str:
    """A test label in words (``posture P / direction D`` in a session with postures)."""
    if label is None or not session.postures:
        return str(label)
    p, d = session.split(label)
    return f"posture {p} / direction {d}"
