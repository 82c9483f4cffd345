"""Withheld-effect benchmark: data sets from a richer truth model, diagnosed blind, scored afterwards.

The generator (:func:`generate_cases`) draws, per case, individual strengths around the baseline and
injects zero, one or two registered effects with parameters of clear size (a share ``clear_size`` of the
way from neutral to the far end of each parameter's range), simulates the maximum forces with the
extended model and multiplies them by log-normal measurement noise. The cases keep their labels; the
diagnosis (:func:`neckstrength.gap.diagnose.diagnose`) receives only :class:`BlindData` - an anonymous
name and the noisy forces, in shuffled order - and never imports this module. Only then
:func:`score_benchmark` compares: confusion matrix of injected vs identified effect, error of the
estimated effect size, and the held-out gap shrinkage achieved vs possible (the gap left when predicting
the noiseless forces exactly, i.e. the noise floor).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.stats import beta as beta_dist

from neckstrength.estimation.discrepancy import data_discrepancy
from neckstrength.gap.calibrate import power_for, power_summary
from neckstrength.gap.diagnose import BlindData, DatasetDiagnosis, DiagnosisSettings, diagnose
from neckstrength.gap.effects import EFFECTS, GapContext, available_effects, compose, effect_label, parse_label
from neckstrength.gap.fit import Simulator, make_cache
from neckstrength.gap.store import batch_checkpoints
from neckstrength.wrench.batched import single_threaded_blas


@dataclass(frozen=True)
class BenchmarkSettings:
    effects: tuple[str, ...] = ("cocontraction", "direction_tolerance", "kinematic", "asymmetry", "finer_groups",
                                "origin_offset", "point_scale", "shoulder_girdle")
    pairs: tuple[tuple[str, str], ...] = ()
    replicates: int = 2
    controls: int = 2
    noise_rel: float | tuple[float, float] = 0.05     # one value, or a range drawn per case (uniform)
    strength_spread: float = 0.3
    clear_size: tuple[float, float] = (0.6, 1.0)
    min_force_ratio: float = 0.2
    max_tries: int = 200
    mismatch_replicates: int = 0                      # per effect: cases whose truth also has finer_groups at 1
    mismatch_effect: str = "finer_groups"


@dataclass
class Case:
    """One generated data set, with its label (generator side only)."""

    name: str
    injected: tuple[str, ...]
    theta: dict
    f_true: np.ndarray
    forces_clean: np.ndarray
    forces: np.ndarray
    tier: str = "base"                 # 'base' or 'mismatch' (truth: finer muscle control in addition)
    noise: float = 0.0
    size_share: float = 0.0            # injected size: share of the way from neutral to the far bound

    @property
    def label(self) -> str:
        return effect_label(self.injected)


def _draw_theta(effect, u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    th = []
    for p, ui in zip(effect.params(), u):
        up, down = p.hi - p.neutral, p.neutral - p.lo
        if up > 1e-12 and down > 1e-12:
            far = p.hi if rng.random() < 0.5 else p.lo
        else:
            far = p.hi if up >= down else p.lo
        th.append(p.neutral + ui * (far - p.neutral))
    return np.array(th)


def generate_cases(ctx: GapContext, s: BenchmarkSettings, rng: np.random.Generator) -> list[Case]:
    """Cases: ``controls`` without effect, ``replicates`` per injected effect and per injected pair.

    A draw (strengths and effect size) is kept only if every direction's force is at least
    ``min_force_ratio`` x the median force of the same strengths without the effect (Table A.2: the weakest
    direction of a participant is 0.2-0.6 of the median), so that no case has directions a participant could
    hardly have produced at all."""
    effects = {e.name: e for e in available_effects(ctx, list(dict.fromkeys(
        list(s.effects) + [n for pr in s.pairs for n in pr])))}
    missing = [n for n in list(s.effects) + [n for pr in s.pairs for n in pr] if n not in effects]
    if missing:
        raise ValueError(f"benchmark effects not applicable to model {ctx.model.name}: {missing}")
    plan: list[tuple[tuple[str, ...], str]] = [((), "base")] * s.controls
    for n in s.effects:
        plan += [((n,), "base")] * s.replicates
    for pr in s.pairs:
        plan += [(tuple(pr), "base")] * s.replicates
    if s.mismatch_replicates:
        mm = available_effects(ctx, [s.mismatch_effect])
        if not mm:
            raise ValueError(f"mismatch effect {s.mismatch_effect} not applicable to {ctx.model.name}")
        effects[mm[0].name] = mm[0]
        for n in s.effects:
            if n != mm[0].name:
                plan += [((n,), "mismatch")] * s.mismatch_replicates
    cache = make_cache()
    base_sim = Simulator(ctx, compose(ctx, [], []), cache)
    pidx = base_sim.pidx
    p = int(pidx.max()) + 1
    cases = []
    for names, tier in plan:
        for _ in range(s.max_tries):
            f = ctx.model.strengths * np.exp(rng.normal(0.0, s.strength_spread, p))[pidx]
            us = {n: rng.uniform(*s.clear_size, effects[n].n_params) for n in names}
            theta = {n: _draw_theta(effects[n], us[n], rng) for n in names}
            extra = {}
            if tier == "mismatch":
                extra = {s.mismatch_effect: _draw_theta(effects[s.mismatch_effect],
                                                        np.ones(effects[s.mismatch_effect].n_params), rng)}
            allth = {**theta, **extra}
            inst = compose(ctx, [effects[n] for n in allth], [allth[n] for n in allth])
            clean = Simulator(ctx, inst, cache).forces(f[None])[0]
            typical = np.median(base_sim.forces(f[None])[0])
            if clean.min() >= s.min_force_ratio * typical:
                break
        else:
            raise RuntimeError(f"could not draw a producible case for {names}")
        nz = (float(rng.uniform(*s.noise_rel)) if isinstance(s.noise_rel, (tuple, list)) else float(s.noise_rel))
        noisy = clean * np.exp(rng.normal(0.0, nz, len(clean)))
        share = max((float(np.max(us[n])) for n in names), default=0.0)
        cases.append(Case("", tuple(names), theta, f, clean, noisy, tier, nz, share))
    order = rng.permutation(len(cases))
    cases = [cases[k] for k in order]
    for k, c in enumerate(cases):
        c.name = f"case{k + 1:02d}"
    return cases


def blind(cases: Sequence[Case]) -> list[BlindData]:
    """What the diagnosis may see: anonymous names and noisy forces."""
    return [BlindData(c.name, c.forces.copy()) for c in cases]


def _theta_from(diag: DatasetDiagnosis, effect: str):
    row = diag.effects[diag.effects["candidate"] == effect]
    if row.empty:
        return None
    vals = json.loads(row["theta_values"].iloc[0])
    return None if effect not in vals else np.array(vals[effect], float)


def score_benchmark(ctx: GapContext, cases: Sequence[Case], diags: Sequence[DatasetDiagnosis],
                    epsilon: float = 3.0, power: dict[str, pd.DataFrame] | None = None) -> dict[str, pd.DataFrame]:
    """Confusion matrix, per-case table (identified vs injected, gaps) and effect-size errors. ``power``: per
    case name, a power summary (:func:`neckstrength.gap.calibrate.power_summary`) to use instead of the
    diagnosis's own (:func:`benchmark_power`)."""
    by_name = {d.name: d for d in diags}
    power = power or {}
    rows, size_rows = [], []
    for c in cases:
        d = by_name[c.name]
        tab = d.effects.set_index("candidate")
        ident = d.summary["chosen"]
        gap_base = float(tab.loc["none", "gap_cv"])
        gap_chosen = float(tab.loc[ident, "gap_cv"])
        gap_inj = float(tab.loc[c.label, "gap_cv"]) if c.label in tab.index else np.nan
        floor = float(1 - data_discrepancy(c.forces_clean, c.forces, epsilon).mean())
        possible = gap_base - floor
        pws = power.get(c.name, d.power_summary)
        min_share = (float(pws.set_index("effect").loc[c.label, "min_detectable_share"])
                     if len(pws) and c.label in set(pws["effect"]) else np.nan)
        rows.append({"case": c.name, "injected": c.label, "tier": c.tier, "noise": c.noise,
                     "noise_estimated": float(d.summary.get("noise_sigma", np.nan)),
                     "size_share": c.size_share, "min_detectable_share": min_share,
                     "detectable": bool(np.isfinite(min_share) and c.size_share >= min_share),
                     "p_value": d.summary.get("p_value", np.nan),
                     "theta_true": "; ".join(f"{n}: {EFFECTS[n](ctx).describe(th)}" for n, th in c.theta.items()) or "-",
                     "identified": ident, "p_best": d.summary["p_best_chosen"],
                     "correct": ident == c.label,
                     "overlap": (ident == c.label) or bool(set(c.injected) & set(parse_label(ident))),
                     "gap_base": gap_base, "gap_chosen": gap_chosen, "gap_injected_effect": gap_inj,
                     "gap_noise_floor": floor, "shrink_achieved": gap_base - gap_chosen, "shrink_possible": possible,
                     "shrink_share": (gap_base - gap_chosen) / possible if possible > 1e-9 else np.nan})
        for n, th in c.theta.items():
            est = _theta_from(d, n)
            eff = EFFECTS[n](ctx)
            for k, prm in enumerate(eff.params()):
                e = np.nan if est is None else float(est[k])
                size_rows.append({"case": c.name, "injected": c.label, "effect": n, "parameter": prm.name,
                                  "true": float(th[k]), "estimated": e, "error": e - float(th[k]),
                                  "error_share_of_range": (e - float(th[k])) / (prm.hi - prm.lo),
                                  "identified": ident})
    per_case = pd.DataFrame(rows)
    labels_inj = list(dict.fromkeys(["none"] + sorted(set(per_case["injected"]) - {"none"})))
    labels_id = list(dict.fromkeys(labels_inj + sorted(set(per_case["identified"]))))
    conf = pd.crosstab(pd.Categorical(per_case["injected"], labels_inj),
                       pd.Categorical(per_case["identified"], labels_id), dropna=False)
    conf.index.name = "injected \\ identified"
    conf.columns.name = None
    conf = conf.reset_index()
    return {"per_case": per_case, "confusion": conf, "effect_size": pd.DataFrame(size_rows),
            "accuracy": accuracy_table(per_case)}


def share_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Clopper-Pearson (exact binomial) interval of a share ``k / n``: its coverage is at least ``level`` for
    every true share (conservative), so a benchmark's small counts are not overread."""
    if n == 0:
        return (np.nan, np.nan)
    a = (1 - level) / 2
    lo = float(beta_dist.ppf(a, k, n - k + 1)) if k > 0 else 0.0
    hi = float(beta_dist.ppf(1 - a, k + 1, n - k)) if k < n else 1.0
    return lo, hi


def accuracy_table(pc: pd.DataFrame) -> pd.DataFrame:
    """Share correct by group: controls (false alarms), effect cases by detectability (item 3's power), by tier,
    by injected size and by injected effect, each with its exact 95% interval (:func:`share_interval`) and, for
    the two groups issue 17 sets goals for, the goal (>= 0.8 correct on detectable cases; <= 0.1 false alarms,
    i.e. >= 0.9 correct controls) and whether the observed share meets it."""
    rows = []

    def add(group, sel, goal=np.nan):
        g = pc[sel]
        k, n = (int(g["correct"].sum()), len(g)) if len(g) else (0, 0)
        lo, hi = share_interval(k, n)
        share = k / n if n else np.nan
        rows.append({"group": group, "cases": n, "correct": k, "share_correct": share,
                     "ci95_low": lo, "ci95_high": hi,
                     "named_any_effect": int((g["identified"] != "none").sum()) if n else 0,
                     "named_wrong_effect": int(((g["identified"] != "none") & ~g["correct"].astype(bool)).sum())
                     if n else 0,
                     "goal_share_correct": goal,
                     "goal_met": ("" if not np.isfinite(goal) else "no cases" if n == 0
                                  else "yes" if share >= goal else "no")})

    ctrl = pc["injected"] == "none"
    add("controls (no effect): correct = none", ctrl, 0.9)
    eff = ~ctrl
    add("effect cases, detectable by the case's power analysis", eff & pc["detectable"], 0.8)
    add("effect cases, not detectable by the power analysis", eff & ~pc["detectable"])
    some = eff & np.isfinite(pc["min_detectable_share"].astype(float)) if "min_detectable_share" in pc else eff & False
    add("effect cases whose effect is detectable at some simulated size (whatever the injected size)", some)
    add("effect cases whose effect is undetectable at every simulated size", eff & ~some)
    for tier in sorted(set(pc["tier"])):
        add(f"effect cases, tier {tier}, detectable", eff & pc["detectable"] & (pc["tier"] == tier))
        add(f"effect cases, tier {tier}, all", eff & (pc["tier"] == tier))
    for lo, hi in ((0.0, 0.4), (0.4, 0.7), (0.7, 1.01)):
        add(f"effect cases, injected size {lo:g}-{min(hi, 1):g} of the range", eff & (pc["size_share"] >= lo)
            & (pc["size_share"] < hi))
    for e in sorted(set(pc.loc[eff, "injected"])):
        add(f"injected {e}", pc["injected"] == e)
    return pd.DataFrame(rows)


def benchmark_power(ctx: GapContext, cases: Sequence[Case], diags: Sequence[DatasetDiagnosis],
                    ds: DiagnosisSettings, progress=None, store=None, chunk: int | None = None,
                    workers: int = 1) -> dict[str, pd.DataFrame]:
    """Power summary of each single-effect case for its injected effect only (scoring side: the case's label
    chooses which effect's power is simulated; the diagnosis's decision, made blind, does not use the power).

    The same simulated data sets, screen and decision as the diagnosis's own power table would use for that
    effect (:func:`neckstrength.gap.calibrate.power_for` with the case's calibration), i.e. 8 instead of
    ``9 effects x 8`` simulated data sets per case. ``store``/``chunk`` as in
    :func:`neckstrength.gap.diagnose.diagnose` (stored as each batch finishes; an interrupted run resumes);
    ``workers``: processes sharing out the effects of the screen (the answers do not depend on it)."""
    say = progress or (lambda msg: None)
    by_name = {d.name: d for d in diags}
    todo = [c for c in cases if len(c.injected) == 1 and by_name[c.name].calibration is not None
            and ds.calibration.power_replicates > 0]
    key = {c.name: BlindData(f"{c.name}/power/{c.label}", c.forces.copy()) for c in todo}
    out = {}
    for c in todo:
        got = store.get(key[c.name]) if store is not None else None
        if got is not None:
            out[c.name] = got
    rest = [c for c in todo if c.name not in out]
    n = max(1, int(chunk)) if chunk else max(1, len(rest))
    with single_threaded_blas():
        for a in range(0, len(rest), n):
            part = rest[a:a + n]
            say(f"power of the injected effect: cases {a + 1}-{a + len(part)} of {len(rest)} "
                f"({len(todo) - len(rest)} resumed)")
            ckp = batch_checkpoints(store, [key[c.name] for c in part])
            tabs = power_for(ctx, blind(part), [by_name[c.name].calibration for c in part],
                             [[c.label] for c in part], ds, say, workers, ckp)
            for c, t in zip(part, tabs):
                out[c.name] = power_summary(t, ds.calibration.power_target)
                if store is not None:
                    store.put(key[c.name], out[c.name])
            if ckp is not None:
                ckp.clear()
    return out


def _benchmark_part(ctx: GapContext, part: Sequence[Case], ds: DiagnosisSettings, store, power_store, tag: str,
                    verbose: bool) -> int:
    """One batch of cases, diagnosed and its power simulated in a worker process; results go to the stores."""
    import time

    t0 = time.perf_counter()

    def say(msg):
        if verbose:
            print(f"[{tag}, {time.perf_counter() - t0:.0f} s] {msg}", flush=True)

    diags = diagnose(ctx, blind(part), decision_settings(ds), say, store=store)
    benchmark_power(ctx, part, diags, ds, say, store=power_store)
    return len(part)


def diagnose_in_workers(ctx: GapContext, parts: Sequence[Sequence[Case]], ds: DiagnosisSettings, store, power_store,
                        workers: int, progress=None, on_done=None, stop=None) -> int:
    """Diagnose (and simulate the power of) batches of cases in ``workers`` processes; every result is written to
    ``store`` / ``power_store`` as its batch finishes (the caller then reads them back: the same code path and the
    same answers as one process, since a data set's diagnosis does not depend on what else is diagnosed with it).
    Batches already stored are resumed by the workers themselves. ``on_done(i)`` is called in this process when
    batch ``i`` is stored; ``stop()`` true: no further batch is started. Returns the number of batches done."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    if store is None or power_store is None:
        raise ValueError("diagnosing in worker processes needs the result stores (the workers write there)")
    say = progress or (lambda msg: None)
    todo = list(range(len(parts)))
    running: dict = {}
    n_done = 0
    with ProcessPoolExecutor(max(1, int(workers)), mp_context=mp.get_context("fork")) as ex:
        while todo or running:
            while todo and len(running) < max(1, int(workers)) and not (stop and stop()):
                i = todo.pop(0)
                running[ex.submit(_benchmark_part, ctx, parts[i], ds, store, power_store,
                                  f"batch {i + 1}/{len(parts)}", progress is not None)] = i
            if not running:
                break
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in finished:
                i = running.pop(f)
                f.result()
                n_done += 1
                say(f"benchmark: batch {i + 1} of {len(parts)} stored ({n_done} batches in this run)")
                if on_done is not None:
                    on_done(i)
    return n_done


def run_benchmark(ctx: GapContext, bs: BenchmarkSettings, ds: DiagnosisSettings, rng: np.random.Generator,
                  progress=None, store=None, chunk: int | None = None, power_store=None, workers: int = 1):
    """Generate, diagnose blind (``store``/``chunk``: see :func:`neckstrength.gap.diagnose.diagnose`), score.

    The diagnoses are made without their power tables (``power_replicates`` 0: the same decision, see
    :func:`neckstrength.gap.calibrate.calibrate`); the detectability of each case's injected effect comes from
    :func:`benchmark_power` (stored in ``power_store``). ``workers`` > 1: with both stores and several batches of
    ``chunk`` cases, the batches in that many processes (:func:`diagnose_in_workers`); with one batch, the
    effects' fits of that batch shared out over that many processes (larger fit batches cost less per case).
    Returns (cases, diagnoses, score tables)."""
    cases = generate_cases(ctx, bs, rng)
    if progress:
        progress(f"benchmark: {len(cases)} cases generated (labels withheld from the diagnosis)")
    n = max(1, int(chunk)) if chunk else max(1, -(-len(cases) // workers))
    if workers > 1 and store is not None and power_store is not None and n < len(cases):
        diagnose_in_workers(ctx, [cases[a:a + n] for a in range(0, len(cases), n)], ds, store, power_store,
                            workers, progress)
    # one batch (or the batches already stored by the workers): here, the effects shared out over ``workers``
    diags = diagnose(ctx, blind(cases), decision_settings(ds), progress, store=store, chunk=chunk, workers=workers)
    power = benchmark_power(ctx, cases, diags, ds, progress, store=power_store, chunk=chunk, workers=workers)
    return cases, diags, score_benchmark(ctx, cases, diags, ds.epsilon, power)


def decision_settings(ds: DiagnosisSettings) -> DiagnosisSettings:
    """The benchmark's diagnosis settings: as ``ds`` without the power tables (the decision is the same)."""
    return replace(ds, calibration=replace(ds.calibration, power_replicates=0))
