#!/usr/bin/env python
"""How well could any method name the user benchmark's effects? A Bayes observer with the truths' families (issue 32).

The user benchmark (``bench_gap_users.py``) scores the diagnosis: detectable effect cases named correctly, false
alarms on the controls. This script asks what the data of that design allow. It regenerates the same cases (same
config seed, stream and design, so ``u001`` here is ``u001`` there) and classifies each with the Bayes rule of an
observer who knows more than the diagnosis:

- the generator's **own effect families and parameter priors** (:mod:`neckstrength.gap.truths`) and the design's
  share of each truth as the prior over truths (the diagnosis has its own candidates, twelve of them);
- the **true noise** level and the recording rule (largest of the trials);
- the case's **true strengths** up to a log-normal factor of SD ``--strength-sd`` (0: exactly; 3: practically
  unknown), or with ``--plug-in`` the base model's strengths **fitted** to the case's forces (then nothing true
  about the case is known beyond the families).

Every family is a Gaussian in the log forces (:class:`Oracle`): the family's clean log forces at those strengths,
averaged over a grid that covers the generator's uniform parameter prior (asymmetry, origin offset, submaximal
effort, posture drift, head/neck size), or the mean and covariance over ``--directions`` push-direction draws of
the generator's own sampler at each of six cone angles (direction errors) or over ``--element-draws`` element
draws (96-element controls); plus the recording noise and the strengths' uncertainty, linearised. The most probable
truth is the answer; stricter rules name an effect only when the posterior probability of "no effect" (base or
96-element control) is below ``--thresholds``.

Scored like the user benchmark: named correctly among the cases that ``--cases`` (that benchmark's ``cases.csv``)
marks model-free detectable, false alarms on the controls, Wilson 95% intervals. ``--check`` repeats every case with
the grids and draws doubled (the approximation's own error).

    nice -n 10 .venv/bin/python benchmarks/bench_gap_oracle.py --cases results/gap/s3m24/users6_r39/cases.csv \\
        --out results/gap/s3m24/oracle --jobs 2                    # add --plug-in for fitted strengths
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.special import logsumexp
from scipy.stats import chi2 as chi2_dist


def _grid(lo: float, hi: float, n: int, signed: bool) -> np.ndarray:
    """Midpoints of ``n`` equal bins of [lo, hi] (a uniform prior), and their negatives if ``signed``."""
    g = lo + (np.arange(n) + 0.5) * (hi - lo) / n
    return np.concatenate([-g, g]) if signed else g


def _sphere(n: int, planar: bool) -> np.ndarray:
    if planar:
        t = 2 * np.pi * (np.arange(n) + 0.5) / n
        return np.c_[np.cos(t), np.sin(t), np.zeros(n)]
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    r = np.sqrt(1 - z ** 2)
    phi = np.pi * (1 + 5 ** 0.5) * k
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


class Oracle:
    """Log marginal likelihood of a case's recorded log forces under each truth family.

    Every family is a Gaussian in the K log forces: the family's clean log forces at the true strengths (per grid
    point of its parameters, or the draws' mean and covariance for the per-test direction errors and the 96-element
    controls) plus the recording noise (largest of ``repeats`` trials: the mean and variance of the largest of
    ``repeats`` standard normals times the noise) plus, with ``strength_sd`` > 0, strengths known only up to a
    log-normal factor of that SD around the truth (linearised: ``strength_sd^2 J J'``, J the derivative of the log
    forces in the log free strengths). ``strength_sd = 0``: the strengths are known exactly."""

    def __init__(self, setup, cs, scale: int = 1, directions: int = 200, element_draws: int = 400):
        from neckstrength.gap import truths as T

        self.T, self.setup, self.cs, self.k = T, setup, cs, scale
        self.repeats = cs.repeats
        self.fc = T.TruthForces(setup)
        self.directions, self.element_draws = directions * scale, element_draws * scale
        m = setup.model
        self.grp = np.argmax(m.S, axis=1)
        base = [n[:-2] if (setup.tie_sides and n.endswith(("-R", "-L"))) else n for n in m.muscle_names]
        free = list(dict.fromkeys(base))
        self.pidx = np.array([free.index(b) for b in base])
        self.nfree = len(free)

    def jacobian(self, f: np.ndarray) -> np.ndarray:
        from neckstrength.gap.evidence import log_jacobian

        return log_jacobian(self.fc.base, f, self.pidx)

    def fit_base(self, y: np.ndarray, sigma: float) -> np.ndarray:
        """The base model fitted to the recorded log forces (:func:`neckstrength.gap.evidence.fit_strengths_map`)."""
        from neckstrength.gap.evidence import fit_strengths_map

        return fit_strengths_map(self.fc.base, self.setup.model.strengths, self.pidx, y, sigma, self.cs.repeats)

    def signatures(self, f: np.ndarray, rng: np.random.Generator) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
        """Per truth family, a list of (clean log forces per parameter point [G x K], extra covariance [K x K]):
        the family's likelihood is the average over the list's components and their rows."""
        from dataclasses import replace

        cs, k, T, K = self.cs, self.k, self.T, len(self.fc.N)
        zero = np.zeros((K, K))
        base = self.fc.base(f)
        lb = np.log(base)

        def grid(truth, params):
            return [(np.log([T.make_forces(self.setup, truth, f, p, self.fc) for p in params]), zero)]

        out = {"none": [(lb[None, :], zero)]}
        out["asymmetry"] = grid("asymmetry", [{"log_LR_ratio": v} for v in _grid(*cs.log_lr_ratio, 20 * k, True)])
        r, t = _grid(*cs.offset_m, 5 * k, False), _grid(0, 2 * np.pi, 36 * k, False)
        out["origin_offset"] = grid("origin_offset", [{"dx_m": ri * np.cos(ti), "dy_m": ri * np.sin(ti)}
                                                      for ri in r for ti in t])
        h, n = _grid(*cs.head_scale, 8 * k, True), _grid(*cs.neck_scale, 8 * k, True)
        out["anthropometric_scaling"] = grid("anthropometric_scaling",
                                             [{"head_scale": hi, "neck_scale": ni} for hi in h for ni in n])
        out["posture_drift"] = grid("posture_drift", [{"drift_deg": d} for d in _grid(*cs.drift_deg, 14 * k, False)])
        V = _sphere(400 * k, self.setup.model.planar)
        E = _grid(*cs.effort_min, 10 * k, False)
        out["submaximal_effort"] = [(lb[None, :] + np.log([T.effort_field(self.fc.N, v, e) for v in V for e in E]),
                                     zero)]
        # per-test direction errors: per cone angle, the draws' mean and covariance of the log force change
        out["direction_error"] = []
        for c in _grid(*cs.cone_deg, 6, False):
            one = replace(cs, cone_deg=(c, c))
            d = np.array([np.log(T.make_forces(self.setup, "direction_error", f,
                                               T.draw_params(self.setup, "direction_error", one, rng, self.fc),
                                               self.fc)) - lb for _ in range(self.directions)])
            out["direction_error"].append(((lb + d.mean(axis=0))[None, :], np.cov(d.T)))
        # 96-element controls: likewise over element draws around the group strengths
        m, full = self.setup.model, self.setup.full
        scale = (f / np.where(m.strengths > 0, m.strengths, 1.0))[self.grp]
        d = np.array([np.log(T.make_forces(self.setup, "rich96", f, {}, self.fc,
                                           full.strengths * scale * np.exp(rng.normal(0.0, cs.element_spread, full.m))))
                      - lb for _ in range(self.element_draws)])
        out["rich96"] = [((lb + d.mean(axis=0))[None, :], np.cov(d.T))]
        return out

    def loglik(self, sig, J: np.ndarray, y: np.ndarray, sigma: float, strength_sd: float) -> dict[str, float]:
        from neckstrength.gap.evidence import log_evidence

        return log_evidence(sig, J, y, sigma, strength_sd, self.cs.repeats)


class DiagnosisFamilies:
    """The same observer over **the diagnosis's own explanations** (:class:`neckstrength.gap.evidence.Explanations`:
    its candidates on their screen grids, its aiming-scatter model, its element null as a second "no effect"), with
    :class:`Oracle`'s interface."""

    def __init__(self, setup, ctx, effects, repeats: int, element_draws: int, element_centred: bool = False):
        from neckstrength.gap.evidence import EvidenceSettings, Explanations

        self.setup = setup
        self.e = Explanations(ctx, effects, EvidenceSettings(repeats=repeats, element_draws=element_draws,
                                                             element_centred=element_centred))
        self.repeats = repeats

    def fit_base(self, y, sigma):
        return self.e.fit(y, sigma)

    def explain(self, y, sigma, rng, strengths=None):
        return self.e.explain(y, sigma, rng, strengths)

    def jacobian(self, f):
        from neckstrength.gap.evidence import log_jacobian

        return log_jacobian(self.e.base, f, self.e.pidx, base_rows=self.e.base_rows)

    def signatures(self, f, rng):
        return self.e.signatures(f, rng)

    def loglik(self, sig, J, y, sigma, strength_sd):
        from neckstrength.gap.evidence import log_evidence

        return log_evidence(sig, J, y, sigma, strength_sd, self.e.s.repeats)


def score(rows: pd.DataFrame, thresholds, fit_alpha: float | None = None) -> pd.DataFrame:
    """Named correctly (detectable effect cases) and false alarms (controls) per decision rule, Wilson 95%."""
    from neckstrength.gap.scoring import wilson_interval

    out = []
    ctrl = rows["target"] == "none"
    eff = ~ctrl
    det = eff & rows["detectable"].fillna(False).astype(bool) if "detectable" in rows else eff
    rules = [("most probable truth (MAP)", rows["map_target"])]
    for t in thresholds:
        rules.append((f"effect named only if P(no effect) < {t:g}",
                      np.where(rows["p_no_effect"] < t, rows["best_effect_target"], "none")))
    if fit_alpha is not None and "fit_p_best_effect" in rows:
        for t in thresholds:
            rules.append((f"P(no effect) < {t:g} and the effect fits (chi-square p >= {fit_alpha:g})",
                          np.where((rows["p_no_effect"] < t) & (rows["fit_p_best_effect"] >= fit_alpha),
                                   rows["best_effect_target"], "none")))
    for rule, named in rules:
        named = pd.Series(np.asarray(named), index=rows.index)
        for group, sel, hit in [("detectable effect cases: named correctly", det, named == rows["target"]),
                                ("all effect cases: named correctly", eff, named == rows["target"]),
                                ("controls: an effect named (false alarm)", ctrl, named != "none"),
                                ("base-model controls: false alarm", rows["truth"] == "none", named != "none"),
                                ("96-element controls: false alarm", rows["truth"] == "rich96", named != "none")]:
            n, k = int(sel.sum()), int((sel & hit).sum())
            lo, hi = wilson_interval(k, n)
            out.append({"rule": rule, "group": group, "cases": n, "count": k, "share": k / n if n else np.nan,
                        "wilson95_low": lo, "wilson95_high": hi})
    return pd.DataFrame(out)


_W = {}


def _init(cfg_path, model, cs, scales, directions, element_draws, families: str = "truths",
          element_centred: bool = False):
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_gap_users import settings_for
    from neckstrength.config import load_config
    from neckstrength.gap.truths import TruthSetup

    cfg = load_config(cfg_path)
    ctx, _, effects = settings_for(cfg, model, 1, ())
    setup = TruthSetup.of(ctx)
    if families == "diagnosis":
        oracles = {1: DiagnosisFamilies(setup, ctx, effects, cs.repeats, element_draws, element_centred)}
    else:
        oracles = {k: Oracle(setup, cs, k, directions, element_draws) for k in scales}
    _W.update(seed=cfg["seed"], oracles=oracles, setup=setup)


def _one(job):
    """Log likelihoods and best-fit chi-squares of one case: {(grid scale, strength SD): ({family: ll},
    {family: chi2})}."""
    from neckstrength.gap.evidence import best_fit_chi2
    from neckstrength.seeds import derive_rng

    i, f, y, sigma, sds, plug_in = job
    out = {}
    for k, orc in _W["oracles"].items():
        rng = derive_rng(_W["seed"], "gap-oracle", i, k)
        if hasattr(orc, "explain"):  # the diagnosis's explanations: each effect at strengths refitted under it
            _, sig, J = orc.explain(y, sigma, rng, None if plug_in else f)
        else:
            if plug_in:
                f = orc.fit_base(y, sigma)
            sig = orc.signatures(f, rng)
            J = orc.jacobian(f)
        for sd in sds:
            out[(k, sd)] = (orc.loglik(sig, J, y, sigma, sd),
                            {t: best_fit_chi2(c, J[t] if isinstance(J, dict) else J, y, sigma, sd, orc.repeats)
                             for t, c in sig.items()})
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--model", default=None, help="default: gap.benchmark.model")
    ap.add_argument("--cases", default=None, help="the user benchmark's cases.csv: its model-free 'detectable' "
                    "column (without it every effect case counts)")
    ap.add_argument("--out", required=True, help="folder for oracle_rows.csv, oracle_scores.csv, oracle_summary.json")
    ap.add_argument("--replicates", type=int, default=15, help="cases per effect truth (as the user benchmark run)")
    ap.add_argument("--controls", type=int, default=30)
    ap.add_argument("--rich-controls", type=int, default=10)
    ap.add_argument("--limit", type=int, default=None, help="only the first cases of the stratified order")
    ap.add_argument("--strength-sd", default="0,0.1,0.3", help="log SDs of the strengths' uncertainty around the "
                    "truth (0: known exactly)")
    ap.add_argument("--directions", type=int, default=200, help="push-direction draws per cone angle")
    ap.add_argument("--element-draws", type=int, default=400, help="96-element draws per case")
    ap.add_argument("--thresholds", default="0.2,0.05", help="stricter rules: P(no effect) below these")
    ap.add_argument("--plug-in", action="store_true", help="the strengths of the base model fitted to the case's "
                    "forces instead of the true ones (the oracle then knows only the effect families and priors)")
    ap.add_argument("--seed", type=int, default=None, help="the design's seed (default: the config's, as the user "
                    "benchmark; e.g. 20261128 for its fresh design)")
    ap.add_argument("--noise", choices=("true", "measured"), default="true",
                    help="the noise level the observer uses: the case's true one, or the pooled log SD of its trials "
                    "(what the diagnosis is given)")
    ap.add_argument("--families", choices=("truths", "diagnosis"), default="truths",
                    help="the truths' own families (default) or the diagnosis's candidates, aiming-scatter model and "
                    "element null")
    ap.add_argument("--fit-alpha", type=float, default=0.001, help="rules that also need the named effect to fit: "
                    "its best chi-square p-value (K degrees of freedom) at least this")
    ap.add_argument("--element-centred", action="store_true", help="with --families diagnosis: the element null's "
                    "mean shift without its part in the strengths' span (EvidenceSettings.element_centred)")
    ap.add_argument("--check", action="store_true", help="also with every grid and draw count doubled")
    ap.add_argument("--jobs", type=int, default=1, help="processes")
    ap.add_argument("--force", action="store_true", help="replace the files of an OUT this script wrote before")
    a = ap.parse_args(argv)

    from neckstrength.config import load_config
    from neckstrength.gap.truths import CaseSettings, TARGET, describe, generate_truth_cases
    from neckstrength.io import atomic_write_csv, atomic_write_text
    from neckstrength.seeds import derive_rng

    t0, c0 = time.perf_counter(), time.process_time()
    cfg = load_config(a.config)
    model = a.model or cfg["gap"]["benchmark"]["model"]
    out = Path(a.out)
    if (out / "oracle_rows.csv").exists() and not a.force:
        raise SystemExit(f"{out / 'oracle_rows.csv'} exists; use --force to replace it")
    cs = CaseSettings(replicates=a.replicates, controls=a.controls, rich_controls=a.rich_controls)
    scales = (1, 2) if a.check else (1,)
    sds = [float(x) for x in a.strength_sd.split(",") if x]
    if a.families == "diagnosis":
        scales = (1,)
    _init(a.config, model, cs, scales, a.directions, a.element_draws, a.families, a.element_centred)
    seed = cfg["seed"] if a.seed is None else a.seed
    _W["seed"] = seed
    setup = _W["setup"]
    stream = f"gap-users/{model}"
    cases = generate_truth_cases(setup, cs, derive_rng(seed, stream), limit=a.limit)
    det = None
    if a.cases:
        ref = pd.read_csv(a.cases).set_index("case")
        det = {}
        for c in cases:
            if c.name in ref.index:
                theirs = (ref.loc[c.name, "truth"], ref.loc[c.name, "truth_params"])
                if theirs != (c.truth, describe(c.truth, c.params)):
                    raise SystemExit(f"{a.cases}: case {c.name} is not this design's ({ref.loc[c.name, 'truth']}, "
                                     f"{ref.loc[c.name, 'truth_params']} vs {c.truth}, {describe(c.truth, c.params)})")
                det[c.name] = bool(ref.loc[c.name, "detectable"])
    if a.families == "diagnosis":
        # the diagnosis does not know the design: "no effect" 1/2 (base and finer structure 1/4 each), the rest
        # shared equally by its candidates
        from neckstrength.gap.evidence import NO_EFFECT

        counts = {t: float(np.exp(v)) for t, v in _W["oracles"][1].e.logprior().items()}
        no_effect = NO_EFFECT

        def target_of(t):
            return "none" if t in no_effect else t
    else:
        counts = {"none": cs.controls, "rich96": cs.rich_controls, **{t: cs.replicates for t in cs.truths}}
        no_effect = ("none", "rich96")

        def target_of(t):
            return TARGET[t]
    logprior = {t: np.log(n / sum(counts.values())) for t, n in counts.items()}
    jobs = [(i, c.strengths, np.log(c.forces), c.noise if a.noise == "true" else c.noise_sd, sds, a.plug_in)
            for i, c in enumerate(cases)]
    if a.jobs > 1:
        from multiprocessing import get_context

        pool = get_context("fork").Pool(a.jobs)
        results = pool.imap(_one, jobs)
    else:
        results = map(_one, jobs)
    rows = []
    for i, (c, res) in enumerate(zip(cases, results)):
        for (k, sd), (ll, chi2) in res.items():
            lp = {t: ll[t] + logprior[t] for t in counts if t in ll}
            z = logsumexp(list(lp.values()))
            post = {t: float(np.exp(v - z)) for t, v in lp.items()}
            best = max(post, key=post.get)
            effects = {t: v for t, v in post.items() if t not in no_effect}
            beff = max(effects, key=effects.get)
            rows.append({"case": c.name, "truth": c.truth, "target": TARGET[c.truth],
                         "truth_params": describe(c.truth, c.params), "noise_true": c.noise, "strength_sd": sd,
                         "grid_scale": k, "map_truth": best, "map_target": target_of(best),
                         "p_no_effect": sum(post[t] for t in no_effect), "best_effect_target": target_of(beff),
                         "detectable": det.get(c.name) if det is not None else True,
                         "fit_p_map": float(chi2_dist.sf(chi2[best], len(c.forces))),
                         "fit_p_best_effect": float(chi2_dist.sf(chi2[beff], len(c.forces))),
                         **{f"post_{t}": v for t, v in post.items()}, **{f"ll_{t}": v for t, v in ll.items()}})
        if (i + 1) % 10 == 0 or i + 1 == len(cases):
            print(f"[{time.perf_counter() - t0:.0f} s wall, {time.process_time() - c0:.0f} s CPU here, load "
                  f"{os.getloadavg()[0]:.1f}] {i + 1}/{len(cases)} cases", flush=True)
    df = pd.DataFrame(rows)
    out.mkdir(parents=True, exist_ok=True)
    thresholds = [float(x) for x in a.thresholds.split(",") if x]
    sc = pd.concat([score(g, thresholds, a.fit_alpha).assign(grid_scale=k, strength_sd=sd)
                    for (k, sd), g in df.groupby(["grid_scale", "strength_sd"])])
    atomic_write_csv(df, out / "oracle_rows.csv")
    atomic_write_csv(sc, out / "oracle_scores.csv")
    info = {"seed": seed, "stream": stream, "oracle_stream": "gap-oracle", "cases": len(cases),
            "detectable_from": a.cases, "wall_s": time.perf_counter() - t0, "strength_sd": sds,
            "directions": a.directions, "element_draws": a.element_draws, "check": a.check, "jobs": a.jobs,
            "plug_in": a.plug_in, "families": a.families, "noise": a.noise,
            "element_centred": a.element_centred}
    atomic_write_text(json.dumps(info, indent=2), out / "oracle_summary.json")
    pd.set_option("display.width", 220)
    for (k, sd), g in df.groupby(["grid_scale", "strength_sd"]):
        what = "fitted base-model strengths" if a.plug_in else "the true strengths"
        print(f"\n== grid scale {k}, {what} known up to a log SD of {sd:g}: truth (rows) vs most probable truth")
        print(pd.crosstab(g.truth, g.map_truth).to_string())
    keep = sc["group"].isin(["detectable effect cases: named correctly", "controls: an effect named (false alarm)",
                             "96-element controls: false alarm"])
    print(sc[keep].to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    return {"rows": df, "scores": sc, "info": info}


if __name__ == "__main__":
    main()
