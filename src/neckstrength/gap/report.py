"""Per-data-set gap report (markdown) and its figures."""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.gap.diagnose import DatasetDiagnosis
from neckstrength.plotting import PLANE_TITLES, _save, plt, radar_grid_series


def markdown_table(df: pd.DataFrame, floatfmt: str = ".3g", max_rows: int | None = None) -> str:
    """A GitHub-flavoured markdown table (no extra dependency)."""
    if max_rows is not None:
        df = df.head(max_rows)

    def fmt(v):
        if isinstance(v, (float, np.floating)):
            return "" if np.isnan(v) else format(float(v), floatfmt)
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else "no"
        return str(v).replace("|", "/")

    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for r in df.itertuples(index=False):
        lines.append("| " + " | ".join(fmt(v) for v in r) + " |")
    return "\n".join(lines)


def activation_check(diag: DatasetDiagnosis, measured: np.ndarray | None) -> pd.DataFrame:
    """Model vs Table A.3: one normalised activation per direction (the measured value) against the model's
    mean activation of the EMG-recorded groups at its predicted maximum (all-direction fit), for every
    candidate. Pearson and Spearman correlation across directions, mean levels, mean absolute difference."""
    if measured is None:
        return pd.DataFrame()
    a3 = np.asarray(measured, float)
    rows = []
    for c, act in diag.activations.items():
        ok = np.isfinite(act) & np.isfinite(a3)
        if ok.sum() < 3:
            continue
        x, y = act[ok], a3[ok]
        pear = float(np.corrcoef(x, y)[0, 1]) if x.std() > 0 and y.std() > 0 else np.nan
        rx, ry = pd.Series(x).rank().to_numpy(), pd.Series(y).rank().to_numpy()
        spear = float(np.corrcoef(rx, ry)[0, 1]) if rx.std() > 0 and ry.std() > 0 else np.nan
        rows.append({"candidate": c, "pearson_r": pear, "spearman_rho": spear, "model_mean": x.mean(),
                     "a3_mean": y.mean(), "mean_abs_diff": float(np.abs(x - y).mean())})
    return pd.DataFrame(rows)


def _code(names) -> str:
    return ", ".join(f"`{n}`" for n in names)


def ranking_note(s: Mapping, effects: pd.DataFrame) -> str:
    """Which statistic names the effect and how the bootstrap ranking relates to it: agrees, prefers a pair that
    includes it, or disagrees (then said in bold), and which single effect the score ranking puts first (summary
    ``s``, ranking ``effects``). A report never shows a low P(best) for the named effect without saying why."""
    chosen = s["chosen"]
    named = s.get("named", chosen)
    ef = effects.set_index("candidate")
    pb = ef["p_best"].astype(float)
    calibrated = bool(s.get("calibrated"))
    out = []
    if s.get("decided_by") == "evidence":
        out.append(f"The decision is the Bayes evidence's (`gap.evidence.decides`): it names `{named}`; the calibrated "
                   f"test beside it names `{s.get('named_calibrated', chosen)}`, and what follows is about the "
                   "calibrated test's choice.")
    elif named != chosen:     # aiming scatter: named by the remainder's shape test, not a ranked candidate
        out.append(f"`{named}` is named by the remainder's shape test after the calibrated test's choice `{chosen}`; "
                   "aiming scatter is not a ranked candidate, so the bootstrap says nothing about it.")
    if chosen == "none":
        out.append("No effect is named " + ("by the calibrated test (maxT over single effects)." if calibrated else
                                            "by the score ranking."))
    elif calibrated:
        out.append(f"`{chosen}` is named by the calibrated test (maxT over single effects: the held-out improvement "
                   "on the calibration's screen, standardised by what noise-only replicates give each effect).")
    else:
        out.append(f"`{chosen}` is named by the score ranking alone (uncalibrated: no false-alarm control).")
    if not pb.notna().any():
        return " ".join(out + ["No bootstrap was run."])
    fav = str(pb.idxmax())
    p_fav, p_ch = float(pb[fav]), float(pb.get(chosen, np.nan))
    boot = ("The bootstrap P(best) (share of resampled direction sets in which a candidate, pairs included, has the "
            "lowest score; no false-alarm control) ")
    pair_note = "pairs are not tested, so that addition is not a finding" if calibrated else "pairs cost parameters"
    if fav == chosen:
        out.append(boot + f"agrees: `{chosen}` is its favourite ({p_fav:.2f}).")
    elif chosen == "none":
        out.append(boot + f"prefers `{fav}` ({p_fav:.2f}): a ranking's favourite is not a finding"
                   + (" (pairs are not tested)." if "+" in fav else
                      "; its improvement is within what noise gives." if calibrated else "."))
    elif chosen in fav.split("+"):
        other = [c for c in fav.split("+") if c != chosen]
        out.append(boot + f"prefers the pair `{fav}` ({p_fav:.2f}; `{chosen}` alone {p_ch:.2f}), which includes "
                   f"`{chosen}`: adding {_code(other)} lowers the score further, but {pair_note}.")
    else:
        out.append(f"**The two disagree**: {boot[0].lower() + boot[1:]}prefers `{fav}` ({p_fav:.2f}; `{chosen}` {p_ch:.2f}), "
                   f"which does not include `{chosen}`. Read `{chosen}` as the effect whose improvement noise explains "
                   "least, not as the best description of the data; neither is shown to be the cause.")
    singles = ef.loc[[c for c in ef.index if "+" not in c and c != "none"], "score"].astype(float)
    if chosen != "none" and chosen in singles.index and len(singles):
        top = str(singles.idxmin())
        if top != chosen:
            z = ef["z"].astype(float) if "z" in ef else pd.Series(np.nan, index=ef.index)
            why = (f": an improvement of its size is commoner under noise (z {z[top]:.2f} against {z[chosen]:.2f})"
                   if calibrated and np.isfinite(z[top]) and np.isfinite(z[chosen]) and z[top] < z[chosen] else "")
            out.append(f"Among single effects the lowest score is `{top}`'s ({singles[top]:.3f} against "
                       f"{singles[chosen]:.3f} for `{chosen}`){why}.")
    return " ".join(out)


def _plane_rms(res: pd.DataFrame, col: str, top: int = 2) -> list[tuple[str, float, float]]:
    """The ``top`` planes with the largest RMS of residual column ``col`` (plane, RMS, mean), largest first."""
    rows = []
    for pl in dict.fromkeys(p for ps in res["planes"] for p in str(ps).split(";") if p):
        r = res.loc[res["planes"].astype(str).str.split(";").apply(lambda ps: pl in ps), col].to_numpy(float)
        rows.append((pl, float(np.sqrt(np.mean(r ** 2))), float(r.mean())))
    return sorted(rows, key=lambda t: -t[1])[:top]


def _where_lines(diag: DatasetDiagnosis) -> list[str]:
    """The Summary's 'Where': the base model's planes (by held-out D and by held-out RMS residual) and, after a named
    candidate, its held-out residuals' planes (the Remainder's source), each labelled with what it comes from."""
    s, res = diag.summary, diag.residuals
    fmt = lambda rows: ", ".join(f"`{p}` (RMS {r:.2f}, mean {m:+.2f})" for p, r, m in rows)  # noqa: E731
    lines = [f"- **Where, base model** (no effect; held out: each direction predicted by the fit without its fold): "
             f"lowest held-out D in plane `{s['worst_plane']}` and wrench component `{s['worst_component']}`, "
             f"largest held-out RMS relative residual in {fmt(_plane_rms(res, 'residual_cv'))}; worst held-out "
             f"directions {', '.join(s['worst_directions'])}; the all-direction fit is too weak in "
             f"`{s['model_too_weak_plane']}` (mean residual {s['model_too_weak_mean_residual']:+.2f}) and too strong "
             f"in `{s['model_too_strong_plane']}` ({s['model_too_strong_mean_residual']:+.2f}); directions outside "
             "the model's reach envelope (no strengths within the bounds fit them): "
             f"{', '.join(s['unreachable']) if s['unreachable'] else 'none'}."]
    if s["chosen"] != "none":
        lines.append(f"- **Where, after `{s['chosen']}`** (its held-out residuals, the source of the Remainder below): "
                     f"largest held-out RMS relative residual in {fmt(_plane_rms(res, 'chosen_residual_cv'))}.")
    lines.append(f"  D (Eq. 5.5) and the RMS residual can name different planes: D saturates (a direction missed by "
                 f"more than about 1 / epsilon = {1 / float(s['epsilon']):.2g} of its force scores near 0 however far "
                 "off), so it counts the directions a plane misses; the RMS is set by the largest misses, and "
                 "over-predictions weigh most (model / measured - 1 has no upper bound).")
    return lines


def write_figures(diag: DatasetDiagnosis, directions: pd.DataFrame, out: Mapping[str, str | Path],
                  a3: np.ndarray | None = None) -> set[str]:
    """``out`` keys: radar, where, effects, activation. The activation figure shows Table A.3 (``a3``) against the
    model's predicted activation of the EMG-recorded groups, or without ``a3`` that prediction alone; for a model
    without EMG-recorded groups and no ``a3`` it shows the mean activation of each model muscle group over the test
    directions (base model, all-direction fit: ``diag.muscles``), so that every figure requested is written (the
    pipeline rule declares it) and none is an empty panel. Returns the keys of the figures written."""
    r = diag.residuals.set_index("direction")
    chosen = diag.summary["chosen"]
    d = directions.set_index("name").loc[r.index].reset_index()
    radar_grid_series(d, [("measured", r["measured_N"], {"color": "blue", "ls": "--"}),
                          ("fitted model, all directions", r["fit_N"], {"color": "black", "lw": 2}),
                          ("fitted model, held out", r["heldout_N"], {"color": "grey", "ls": ":"}),
                          (f"{chosen}, held out", r["chosen_heldout_N"], {"color": "red", "lw": 1.5})],
                      out["radar"], f"{diag.name} ({diag.summary['model']}): measured vs model", rlabel="N")
    # where
    fig, ax = plt.subplots(2, 2, figsize=(15, 10))
    res = diag.residuals
    x = np.arange(len(res))
    ax[0, 0].bar(x - 0.2, res["residual"], 0.4, label="all-direction fit", color="black")
    ax[0, 0].bar(x + 0.2, res["residual_cv"], 0.4, label="held out", color="grey")
    bad = (res["reach"] != "reachable").to_numpy()
    if bad.any():   # no legend entry without such a direction
        ax[0, 0].scatter(x[bad], np.zeros(bad.sum()), marker="x", color="red", s=80, zorder=3,
                         label="outside the reach envelope")
    ax[0, 0].set_xticks(x)
    ax[0, 0].set_xticklabels(res["direction"], rotation=80, fontsize=7)
    ax[0, 0].axhline(0, color="k", lw=0.5)
    ax[0, 0].set_ylabel("relative residual (model / measured - 1)")
    ax[0, 0].set_xlabel("test direction")
    ax[0, 0].legend(fontsize=7)
    ax[0, 0].set_title("per direction")
    pl = diag.planes
    y = np.arange(len(pl))
    ax[0, 1].barh(y - 0.2, pl["rms_residual"], 0.4, color="black", label="RMS, all-direction fit")
    ax[0, 1].barh(y + 0.2, pl["rms_residual_cv"], 0.4, color="grey", label="RMS, held out")
    ax[0, 1].scatter(pl["mean_residual_cv"], y, color="red", zorder=3, label="mean, held out")
    ax[0, 1].set_yticks(y)
    ax[0, 1].set_yticklabels([PLANE_TITLES.get(p, p) for p in pl["plane"]], fontsize=8)
    ax[0, 1].axvline(0, color="k", lw=0.5)
    ax[0, 1].legend(fontsize=7)
    ax[0, 1].set_title("by plane of the 3 x 3 grid")
    ax[0, 1].set_xlabel("relative residual (model / measured - 1)")
    co = diag.components
    y = np.arange(len(co))
    ax[1, 0].barh(y - 0.2, co["rms_residual"], 0.4, color="black", label="RMS, all-direction fit")
    ax[1, 0].barh(y + 0.2, co["rms_residual_cv"], 0.4, color="grey", label="RMS, held out")
    ax[1, 0].scatter(co["mean_residual_cv"], y, color="red", zorder=3, label="mean, held out")
    ax[1, 0].set_yticks(y)
    ax[1, 0].set_yticklabels(co["component"], fontsize=8)
    ax[1, 0].axvline(0, color="k", lw=0.5)
    ax[1, 0].legend(fontsize=7)
    ax[1, 0].set_title("by signed wrench component (weight: unit moment / force direction)")
    ax[1, 0].set_xlabel("relative residual, weighted (model / measured - 1)")
    mu = diag.muscles.dropna(subset=["mean_residual"])
    y = np.arange(len(mu))
    ax[1, 1].barh(y - 0.2, mu["mean_residual"], 0.4, color="black", label="mean, all-direction fit")
    ax[1, 1].barh(y + 0.2, mu["mean_residual_cv"], 0.4, color="grey", label="mean, held out")
    ax[1, 1].set_yticks(y)
    ax[1, 1].set_yticklabels(mu["muscle"], fontsize=7)
    ax[1, 1].axvline(0, color="k", lw=0.5)
    ax[1, 1].legend(fontsize=7)
    ax[1, 1].set_title("by active muscle group (weight: activation in the fit)")
    ax[1, 1].set_xlabel("mean relative residual, weighted (model / measured - 1)")
    fig.suptitle(f"Where the model misses: {diag.name} ({diag.summary['model']})")
    fig.tight_layout()
    _save(fig, out["where"])
    # which
    ef = diag.effects
    fig, axe = plt.subplots(figsize=(10, 0.45 * len(ef) + 2))
    y = np.arange(len(ef))[::-1]
    axe.barh(y, ef["score"], color=["red" if c == chosen else ("black" if c == "none" else "grey")
                                     for c in ef["candidate"]])
    base = float(ef.loc[ef["candidate"] == "none", "score"].iloc[0])
    lo = base + ef["delta_ci_low"].to_numpy()
    hi = base + ef["delta_ci_high"].to_numpy()
    axe.errorbar(ef["score"], y, xerr=[np.maximum(ef["score"] - lo, 0), np.maximum(hi - ef["score"], 0)],
                 fmt="none", color="blue", capsize=3, label="90% bootstrap interval (paired with 'none')")
    xt = float(np.nanmax(np.r_[hi, ef["score"].to_numpy()])) * 1.02
    for yi, pb in zip(y, ef["p_best"]):
        axe.text(xt, yi, f"P(best) {pb:.2f}", va="center", fontsize=7)
    axe.set_xlim(0, xt * 1.15)
    axe.set_yticks(y)
    axe.set_yticklabels(ef["candidate"], fontsize=8)
    axe.axvline(base, color="k", lw=0.5)
    axe.set_xlabel(f"held-out gap 1 - D_cv + {diag.summary['penalty_per_param']} x extra parameters (lower is better)")
    axe.legend(fontsize=7, loc="lower right")
    how = "calibrated test" if diag.summary.get("calibrated") else "score ranking, uncalibrated"
    red = (f"red: the calibrated test's choice (named by the Bayes evidence: {diag.summary.get('named', 'none')})"
           if diag.summary.get("decided_by") == "evidence" else f"red: named ({how})")
    axe.set_title(textwrap.fill(f"Which effect: {diag.name} ({diag.summary['model']}); {red}, "
                                "P(best): bootstrap of the score ranking, pairs included", 90), fontsize=10)
    fig.tight_layout()
    _save(fig, out["effects"])
    written = {k for k in ("radar", "where", "effects") if k in out}
    series = [(c, kw) for c, kw in (("none", {"color": "black"}), (chosen, {"color": "red"}))
              if c in diag.activations and np.isfinite(diag.activations[c]).any()]
    if "activation" in out and a3 is None and not series:
        _group_activation_figure(diag, out["activation"])
        written.add("activation")
    elif "activation" in out:
        fig, axa = plt.subplots(figsize=(12, 5))
        if a3 is not None:
            axa.plot(x, a3, "b--o", label="Table A.3 (measured, normalised)")
        for c, kw in dict(series).items():
            axa.plot(x, diag.activations[c], marker="s", label=f"model ({c}): mean EMG-group activation", **kw)
        axa.set_xticks(x)
        axa.set_xticklabels(res["direction"], rotation=80, fontsize=7)
        axa.set_ylim(0, 1.05)
        axa.set_xlabel("test direction")
        axa.set_ylabel("normalised activation (0-1)")
        axa.legend(fontsize=8)
        axa.set_title(f"Withheld activation data vs model prediction: {diag.name}" if a3 is not None else
                      f"Predicted activation at the model's maximum: {diag.name} (no measured activation: what EMG "
                      "would show if the model is right)")
        fig.tight_layout()
        _save(fig, out["activation"])
        written.add("activation")
    return written


def has_emg_prediction(diag: DatasetDiagnosis) -> bool:
    """Whether the diagnosis predicts the activation of EMG-recorded groups (the model has such groups)."""
    return any(np.isfinite(np.asarray(v, float)).any() for v in diag.activations.values())


def _group_activation_figure(diag: DatasetDiagnosis, out) -> None:
    """The activation figure of a model without EMG-recorded groups and without measured activation: each model
    muscle group's mean activation over the test directions at the base model's fitted maxima."""
    mu = diag.muscles
    k = len(diag.residuals)
    fig, axa = plt.subplots(figsize=(max(6.0, 0.35 * len(mu) + 2), 5))
    axa.bar(np.arange(len(mu)), mu["activation_sum"].to_numpy(float) / k, color="black")
    axa.set_xticks(np.arange(len(mu)))
    axa.set_xticklabels(mu["muscle"], rotation=80, fontsize=7)
    axa.set_ylim(0, 1.05)
    axa.set_xlabel("model muscle group")
    axa.set_ylabel(f"mean activation over the {k} test directions (0-1)")
    title = (f"Predicted activation by muscle group: {diag.name} (base model at its fitted maxima; no EMG-recorded "
             "group and no measured activation)")
    axa.set_title(textwrap.fill(title, 90, break_on_hyphens=False), fontsize=10)
    fig.tight_layout()
    _save(fig, out)


def _calibration_lines(diag: DatasetDiagnosis) -> list[str]:
    s = diag.summary
    if not s.get("calibrated"):
        return ["## Decision", "", "Uncalibrated: no noise-only replicates were simulated (`gap.calibration."
                "replicates` = 0); the candidate with the best score is reported without a p-value.", ""]
    by_ev = s.get("decided_by") == "evidence"
    head = (["## Decision (Bayes evidence; the calibrated test beside it)", "",
             f"- **Named effect**: {s['decision']}. The rule (P(no effect) below the threshold and the effect fits) was "
             "chosen on the user benchmark's first design and checked on its second (docs/gap_diagnosis.md, The "
             "decision)."] if by_ev else ["## Decision (calibrated)", ""])
    lines = [*head,
             (f"- **Calibrated test** (the decision before 2026-11-28): {s.get('decision_calibrated', '')}. "
              if by_ev else f"- **Named effect**: {s['decision']}. ") + "Adjusted p-value {s['p_value']:.3g} (maxT over "
             f"{len(diag.power_summary)} effects; {s['replicates']} noise-only replicates simulated from this data "
             f"set's fitted base model, so p-values have resolution {s['p_resolution']:.3g}); the raw p-value of "
             f"the best effect `{s['best_effect_calibrated']}` alone is {s['p_raw_best']:.3g}.",
             f"- **Scope of the p-value** (null truths `{s.get('null_truth', 'base')}`, `gap.calibration.null_truth`):"
             f" the replicates are {s.get('null_note') or 'the fitted model plus noise'}; its false-alarm rate "
             f"{s['alpha']:g} holds for data of that structure (docs/gap_diagnosis.md, Calibration).",
             f"- **Noise level** of the replicates: log-normal SD {s['noise_sigma']:.3f}, source "
             f"`{s['noise_source']}`" + (f": {s['noise_note']}" if s.get("noise_note") else "") + ".",
             f"- **Remainder** (from the held-out residuals of `{s['chosen']}`; planes ranked by RMS relative "
             f"residual, as in the Summary's 'Where, {'base model' if s['chosen'] == 'none' else 'after'}'): "
             f"{s['remainder']} (plane structure of the held-out residuals "
             f"{s['remainder_structure']:.2f},"
             f" p = {s['p_remainder_structure']:.3g}"
             + (f"; held-out gap p = {s['p_remainder_gap']:.3g} against noise-only replicates at SD "
                f"{s['noise_sigma']:.3f}" if np.isfinite(s.get('p_remainder_gap', np.nan))
                else "; the held-out gap itself is not tested because the noise level was estimated from it")
             + "). Held-out RMS log residual of the named candidate "
             f"{s.get('rms_heldout_log_chosen', np.nan):.3f} = {s.get('gap_over_noise', np.nan):.1f} x the noise "
             f"(noise-only replicates: median {s.get('gap_over_noise_null_median', np.nan):.1f} x; held-out "
             "residuals exceed the noise because the strengths are fitted without the held-out directions).",
             *([f"- **Caveat**: `{s['chosen']}` is {'the calibrated test choice' if by_ev else 'named'}, but the gap "
                "that remains is not explained. The noise-only "
                "replicates come from the fitted model, which that gap contradicts; an effect that absorbs part of an "
                "unrelated misfit also beats them. Read the named effect as reducing the misfit by more than noise "
                "would, not as its cause (docs/gap_diagnosis.md, Current results)."]
               if s.get("chosen", "none") != "none" and s.get("remainder_unexplained") else []),
             *([f"- **Aiming scatter** (a random push direction per test; docs/gap_diagnosis.md, Aiming scatter): "
                f"slope test of the squared held-out residuals on the tests' direction sensitivity p = "
                f"{s['scatter_p']:.3g} (named where the remainder is not explained and p <= {s['scatter_alpha']:g}; "
                f"{'named' if s.get('scatter_named') else 'not named'}), cone estimate "
                f"{s['scatter_cone_deg']:.1f} deg (heuristic)."] if "scatter_p" in s else []),
             *_evidence_lines(s), "",
             *_sensitivity_lines(s),
             "### Power per effect", "",
             "Smallest simulated effect size (share of the way from neutral to the far bound of its range) that this "
             f"diagnosis names in at least {100 * s['power_target']:.0f}% of the data sets simulated from this "
             "data set's fitted model at its noise level:", ""]
    lines += [f"- `{r.effect}`: {r.statement}" for r in diag.power_summary.itertuples()]
    lines += ["", markdown_table(diag.power), ""]
    return lines


def _evidence_lines(s: dict) -> list[str]:
    """The Bayes evidence's line (``gap.evidence``; the decision or a second reading), with its choices and its fit
    check."""
    e = s.get("evidence")
    if not e:
        return []
    top = "; ".join(f"`{k}` {v:.2g}" for k, v in e["top3"])
    fit = ("fits" if e["fits"] else "does **not** fit") + f" (chi-square p = {e['fit_p_most_probable']:.2g})"
    named = f"names `{e['named']}`" if e["named"] != "none" else "names nothing"
    role = ("Bayes evidence** (the decision; probabilities heuristic" if s.get("decided_by") == "evidence" else
            "Second reading: Bayes evidence** (heuristic, not the decision")
    return [f"- **{role}; `gap.evidence`: strengths known to a "
            f"log SD of {e['strength_sd']:g}, prior P(no effect) {e['prior_no_effect']:g}, noise "
            f"{e['noise_sigma']:.3f}, each recorded force the largest of {e['trials_per_force']} trial(s); "
            f"docs/gap_diagnosis.md, What the 25 tests allow): most probable `{e['most_probable']}`, which {fit}; "
            f"P(no effect) {e['p_no_effect']:.2g}; top three {top}. It {named} (an effect is named where P(no effect)"
            f" < {e['threshold']:g} and the effect fits at p >= {e['fit_alpha']:g})."
            + ("" if e["fits"] else " No explanation fits: the posterior says which is least bad, not what is true.")]


def _sensitivity_lines(s: dict) -> list[str]:
    """The decision at the ends of the noise's range (summary 'sensitivity')."""
    rows = s.get("sensitivity") or []
    if len(rows) < 2:
        return []
    cols = ["noise", "sigma", "replicates", "named", "p_value", "best", "remainder", "p_remainder_gap",
            "p_remainder_structure", "gap_over_noise"]
    tab = pd.DataFrame(rows)
    tab = tab[[c for c in cols if c in tab]]
    return ["### Sensitivity to the noise level", "",
            "The same decision with noise-only replicates at the ends of the noise's range (the prior's low and "
            "high values, or the repeat-trial estimate's 95% interval; `replicates` noise-only data sets each, so "
            "p-values have resolution 1 / (replicates + 1); no power); `gap_over_noise`: held-out RMS log residual "
            "of the named candidate / noise SD.", "",
            markdown_table(tab), ""]


def _discrimination_lines(diag: DatasetDiagnosis) -> list[str]:
    """Which additional measurements would tell the leading candidates apart (gap.discriminate)."""
    info = diag.summary.get("discrimination")
    if not info:
        return []
    lines = ["## Which tests would tell the leading candidates apart", ""]
    if not info.get("proposed"):
        return lines + [f"No additional measurements proposed: {info.get('note', 'none found')}.", ""]
    tab = getattr(diag, "discrimination", pd.DataFrame())
    pairs = "; ".join(f"`{k}`: {v[0]:.2f} if the first is true, {v[1]:.2f} if the second is"
                      for k, v in info["expected_log_bf"].items())
    lines += [(f"The best candidate's bootstrap P(best) is {info['p_best_top']:.2f} (< {info['threshold']:g}), so the "
              f"ranking does not separate {', '.join(f'`{c}`' for c in info['candidates'])}. Measuring "
              f"**{', '.join(info['measurements'])}** (greedy, objective `{info['objective']}` over the pairs, from a "
              f"pool of {info['pool_size']} measurements: repeats of the test directions (`#2`) and points `azAAA_elEE` "
              f"on the reconstructed head surface, force along its outward normal) has an expected log Bayes factor "
              f"per pair of {pairs}."),
              (f"Predictive of each candidate: its fit on all directions (effect parameters as in the ranking), "
              f"log-normal noise SD {info['sigma']:.3f} ({info['noise_source']})"
              + (" plus its parameter uncertainty (Laplace)" if info.get("parameter_uncertainty", True) else "")
              + ". A log Bayes factor of 1 is odds of e:1; the values are expectations under the model, "
              "not calibrated error rates."
              + (f" Not separable by any force measurement in the pool: {'; '.join(info['indistinguishable_pairs'])}."
                 if info.get("indistinguishable_pairs") else "")), ""]
    if len(tab):
        show = tab[["step", "measurement", "kind", "planes", "candidate_a", "candidate_b", "force_a_N", "force_b_N",
                    "elbf_if_a", "elbf_if_b", "cum_elbf_if_a", "cum_elbf_if_b"]]
        lines += [markdown_table(show), "",
                  ("`elbf_if_a`: expected log Bayes factor of this measurement alone for `candidate_a` over "
                  "`candidate_b` if `candidate_a` is true (`_if_b`: the reverse); `cum_*`: of all proposed "
                  "measurements up to this step (`discrimination.csv` has the points and normals)."), ""]
    return lines


def _protocol_lines(diag: DatasetDiagnosis) -> list[str]:
    """What to measure to tell each effect from noise (gap.protocols): the report's last section."""
    s = diag.summary
    adv = s.get("protocol_advice")
    if not adv:
        return []
    tab = getattr(diag, "protocols", pd.DataFrame())
    lines = ["## What to measure to tell", ""]
    if len(tab):
        piv = tab.pivot_table(index=["effect", "size_share"], columns="protocol", values="power", sort=False,
                              dropna=False)
        piv = piv.reset_index()
        k = s.get("protocol_efficiency", np.nan)
        scale = (f"with the noncentrality divided by {k:.3g}, the factor that matches the present tests' linearised "
                 "power to this calibration's simulated power" if np.isfinite(k) else
                 "of a likelihood-ratio test that knows the effect's form (the calibration's simulated power is 0 "
                 "at every size or absent, so the diagnosis's own efficiency could not be fitted: optimistic)")
        lines += [(f"Power of each protocol at this data set's noise (log SD {s['noise_sigma']:.3f}, "
                   f"{s['noise_source']}): linearised likelihood-ratio power {scale} (gap.protocols, "
                   "docs/gap_diagnosis.md). Heuristic, not calibrated probabilities; empty: the effect at that size "
                   "cannot produce every test."), "", markdown_table(piv, ".2f"), ""]
    lines += [f"- {a}" for a in adv]
    return lines + [""]


def _update_lines(diag: DatasetDiagnosis) -> list[str]:
    """The top candidates' posterior given additional trials (gap.discriminate.update_with_trials)."""
    info = diag.summary.get("update")
    if not info:
        return []
    tab = getattr(diag, "update", pd.DataFrame())
    return ["## Additional trials", "",
            (f"{info['trials']} additional trial(s) ({', '.join(info['measurements'])}) favour "
             f"**{info['favoured']}**. Posterior probabilities with an equal prior over the top candidates, from each "
             f"candidate's predictive of the new trials (its fit on the measured directions, log-normal noise SD "
             f"{info['sigma']:.3f}, parameter uncertainty): they assume that one of these candidates is true and are "
             "not calibrated; in simulation this decision gained from the proposed measurements "
             "(docs/gap_diagnosis.md)."), "",
            markdown_table(tab[["candidate", "posterior", "log_predictive"]]) if len(tab) else "", ""]


def write_report(diag: DatasetDiagnosis, path: str | Path, figures: Mapping[str, str], act: pd.DataFrame,
                 settings_text: str) -> str:
    s = diag.summary
    ef = diag.effects.copy()
    show = ef[["rank", "candidate", "n_params", "gap_cv", "rms_rel_cv", "score", "delta_ci_low", "delta_ci_high",
               "p_best", "p_raw", "z", "D_fit", "theta", "at_bound"]]
    res = diag.residuals
    unreach = res[res["reach"] != "reachable"][["direction", "measured_N", "fit_N", "reach_s_min", "reach_s_max",
                                                "reach"]]
    lines = [f"# Gap diagnosis: {s['dataset']} with model {s['model']}", "",
             f"{s['n_directions']} test directions, {s['folds']}-fold cross-validation over directions. Gap = "
             f"1 - D (Eq. 5.5/5.6, epsilon = {s['epsilon']}) of held-out predictions; score = gap + "
             f"{s['penalty_per_param']} x extra parameters.", "",
             "## Summary", "",
             *_where_lines(diag),
             f"- **Which**: {s['decision']}"
             + (f"; `{s['chosen']}` fitted at {s['chosen_theta']}" if s['chosen'] != "none" else "")
             + f". {ranking_note(s, diag.effects)}"
             + (f" Parameters at a bound of their range: {s['at_bound']}." if s.get("at_bound", "-") != "-" else ""),
             f"- **How far**: held-out gap {s['gap_before']:.3f} -> {s['gap_after']:.3f}; held-out RMS relative "
             f"residual {s['rms_before']:.3f} -> {s['rms_after']:.3f}; all-direction fit D {s['D_fit_base']:.3f} -> "
             f"{s['D_fit_chosen']:.3f} (the thesis's D(f_c) for this kind of fit).", "",
             *_calibration_lines(diag),
             "## Which effect: ranking", "", markdown_table(show), "",
             "`delta_ci_*`: 90% bootstrap interval (directions resampled) of the score difference to `none`; "
             "`p_best`: share of bootstrap samples in which the candidate ranks first (the score ranking, pairs "
             "included; the named effect is decided by the calibrated test, columns `p_raw` and `z`, single effects "
             "only); `D_fit`: fit on all "
             "directions; `theta`: effect parameters of that fit.", "",
             f"![which]({figures['effects']})", "",
             *_discrimination_lines(diag),
             *_update_lines(diag),
             "## Where: by plane", "", markdown_table(diag.planes.drop(columns=["directions"])), "",
             "## Where: by wrench component", "", markdown_table(diag.components), "",
             "## Where: by active muscle group", "", markdown_table(diag.muscles), "",
             "## Where: reach envelope", "",
             "`s` = log(model / measured) minus its mean over directions; the measured pattern is s = 0. A direction "
             "is out of reach when 0 is outside [s_min, s_max] over all sampled and gradient-pushed strength "
             "vectors within the fit bounds.", "",
             markdown_table(unreach) if len(unreach) else "All directions are within the envelope.", "",
             f"![where]({figures['where']})", "", f"![radar]({figures['radar']})", ""]
    if len(act):
        lines += ["## Withheld activation data (Table A.3)", "",
                  "The diagnosis used forces only. Table A.3 gives one normalised activation per direction; it is "
                  "compared with the model's mean activation of the EMG-recorded groups at its predicted maximum "
                  "(fit on all directions) for each candidate. The LP's activations are one optimal vertex and "
                  "need not be unique; EMG was normalised to each muscle's maximum over all trials.", "",
                  markdown_table(act), ""]
        if "activation" in figures:
            lines += [f"![activation]({figures['activation']})", ""]
    elif "activation" in figures and not has_emg_prediction(diag):
        lines += ["## Predicted activation by muscle group", "",
                  "No measured activation for this data set and no EMG-recorded group in this model. The figure "
                  "shows each model muscle group's mean activation over the test directions at the base model's "
                  "fitted maxima (the activation sums of 'Where: by active muscle group' over the directions): what "
                  "EMG of a group would show on average if the model is right.", "",
                  f"![activation]({figures['activation']})", ""]
    elif "activation" in figures:
        lines += ["## Predicted activation", "",
                  "No measured activation for this data set. The figure shows the model's mean activation of the "
                  "EMG-recorded groups at its predicted maximum (fit on all directions; the base model and the named "
                  "candidate): what surface EMG would show if the model is right.", "",
                  f"![activation]({figures['activation']})", ""]
    lines += ["## Per direction", "", markdown_table(res.drop(columns=["planes"])), "",
              "## Settings", "", settings_text, ""]
    lines += _protocol_lines(diag)
    text = "\n".join(lines)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(text, encoding="utf-8")
    return text
