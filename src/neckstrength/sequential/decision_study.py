"""How well the deficit decision decides, measured on simulated patients (issue 31 item 4).

:func:`run_decision_study` measures every participant of a cohort (:mod:`neckstrength.sequential.cohort`, truths
made apart from the decision's priors) in the order the decision's own criterion (``decision_eig``) picks, under
each protocol:

- ``forces``: forces only;
- ``forces+emg``: with surface EMG bounds of the recorded groups (true activation +- band in every tested direction);
- ``forces+emg+deep``: the deficit group recorded too (fine-wire EMG);
- ``forces+postures``: the test directions in several postures (``postures``, the posture set of
  :mod:`neckstrength.postures`), the decision choosing among every (posture, direction) pair; the neutral tests'
  forces are the ``forces`` protocol's, the other postures' get their own noise (stream ``posture_noise``);
- ``alg4``: the thesis's Algorithm 4 (:func:`neckstrength.abc.stage.run_alg4`) on the ``forces`` protocol's forces
  after ``alg4_tests`` tests (all the directions: its protocol; fewer: the first ones in the order ``alg4_order``
  gives, e.g. the forces protocol's), read as a score: ``score = -log(f_c / f_base)`` of the group (its muscles'
  summed f_c over their summed normal strength), so a lower estimate scores higher. It has no probability, so it
  enters the ROC table only (not the stopping rule or the reliability diagram).

It records after every test the log Bayes factor (also as ``score``, the ROC's score), its Monte Carlo error,
P(deficit), the decision and the misfit guard's statistic (the best fit's RMS).
:func:`roc_table`, :func:`sequential_table` and :func:`reliability_table` summarise it: ROC area and sensitivity
at a 5% false-alarm rate after t tests (the Bayes factor as the score: a threshold on it is a threshold on
P(deficit) for any prevalence), the sequential rule's outcome (decided deficit / no deficit / undecided, and the
tests it took), and the reliability of the printed probability (of the participants given probability p, how
many have the deficit; only meaningful at the cohort's own share of deficits, which the study's prevalence
setting must equal).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import pandas as pd
from scipy.stats import beta as beta_dist

from neckstrength.model.reduction import ReducedModel
from neckstrength.sequential.cohort import CohortSettings, simulate_participant
from neckstrength.sequential.decision import DecisionSettings, DeficitDecision
from neckstrength.sequential.joint import JointSettings

PROTOCOLS = ("forces", "forces+emg", "forces+emg+deep", "forces+postures", "alg4")


@dataclass(frozen=True)
class DecisionStudySettings:
    """The decision study (config ``clinician.decision_study``)."""

    cohort: CohortSettings = CohortSettings()
    protocols: tuple[str, ...] = ("forces",)
    n_max: int = 25
    checkpoints: tuple[int, ...] = (5, 10, 15, 25)
    emg_groups: tuple[str, ...] = ()
    emg_band: float = 0.05
    false_alarm: float = 0.05
    postures: tuple[str, ...] = ("neutral", "flex20", "ext20")   # of the forces+postures protocol
    alg4_tests: tuple[int, ...] = (25,)          # the alg4 protocol: Algorithm 4 after these many tests
    bootstrap_direction: str = "back"            # Algorithm 4's Eq. 5.3 scaling direction (chapter5)
    misfit_level: float = 0.05                   # the calibrated misfit guard flags this share of the model's patients
    # (protocol, k): that protocol measures only the first k deficit and the first k normal patients (its cost);
    # a protocol not named measures every patient
    patients_per_kind: tuple[tuple[str, int], ...] = ()

    def __post_init__(self):
        if not 0 < self.misfit_level < 0.5:
            raise ValueError(f"clinician.decision_study.misfit_level must be in (0, 0.5), got {self.misfit_level}")
        bad = [p for p in self.protocols if p not in PROTOCOLS]
        if bad:
            raise ValueError(f"unknown protocols {bad}; known: {PROTOCOLS}")
        bad = [p for p, k in self.patients_per_kind if p not in PROTOCOLS or int(k) < 1]
        if bad:
            raise ValueError(f"clinician.decision_study.patients_per_kind: {bad} must be protocols ({PROTOCOLS}) "
                             "with at least 1 patient")
        if any("emg" in p for p in self.protocols) and not self.emg_groups:
            raise ValueError("protocols with EMG need emg_groups (the recorded muscle groups)")

    def participants(self, protocol: str | None = None) -> list[int]:
        """The cohort indices measured under ``protocol`` (None: every patient), in the order they are run:
        every patient, or the first ``k`` of each kind (deficit patients are ``0 .. n_deficit - 1`` in the cohort,
        normal ones follow), the two kinds alternating (:func:`interleaved`), so a run stopped part-way has both."""
        n_d, n_n = self.cohort.n_deficit, self.cohort.n_normal
        k = None if protocol is None else dict(self.patients_per_kind).get(protocol)
        if k is None:
            return interleaved(range(n_d), range(n_d, n_d + n_n))
        return interleaved(range(min(k, n_d)), range(n_d, n_d + min(k, n_n)))


def interleaved(a: Sequence[int], b: Sequence[int]) -> list[int]:
    """``a[0], b[0], a[1], b[1], ...``, the longer one's rest at the end: the deficit and normal patients in the
    order a study runs them. Each patient draws from its own index's streams, so the order changes no result."""
    a, b = list(a), list(b)
    out = [x for pair in zip(a, b) for x in pair]
    n = min(len(a), len(b))
    return out + a[n:] + b[n:]


def run_decision_study(model: ReducedModel, directions: Sequence[str], U: np.ndarray, force_scale: np.ndarray,
                       f0: np.ndarray, decision: DecisionSettings, joint: JointSettings,
                       study: DecisionStudySettings, rng_for: Callable[[str, int], np.random.Generator],
                       participants: Sequence[int] | None = None, n_threads: int = 1,
                       progress: Callable[[str], None] | None = None,
                       on_participant: Callable[[pd.DataFrame], None] | None = None, pset=None, abc=None,
                       alg4_order: Callable[[int], Sequence[str]] | None = None,
                       one_blas_thread: bool = True) -> pd.DataFrame:
    """One row per participant, protocol and test count t (0 = before any test; the alg4 protocol: one row per
    ``alg4_tests``). Participant ``i`` is drawn from ``rng_for('truth', i)``; both hypotheses' samplers from
    ``rng_for('candidates', i)`` (the same for every protocol of a participant). ``abc``: Algorithm 4's settings
    (:class:`~neckstrength.abc.algorithm4.ABCSettings`, the alg4 protocol); ``alg4_order(i)``: participant ``i``'s
    test order for Algorithm 4 after fewer tests than directions.

    ``one_blas_thread``: numpy's BLAS on one thread throughout
    (:func:`~neckstrength.wrench.batched.single_threaded_blas`). The samplers' products are small (candidates x
    muscles, the dual bounds of the Metropolis-Hastings moves) and the study runs one patient per core, so a
    multi-threaded BLAS only synchronises and spins: a forces-only s3m24 patient took about twice the CPU time
    with it (benchmarks/bench_decision_speed.py). The numbers are the same (each product is computed the same
    way; the benchmark compares every test's log BF)."""
    from neckstrength.wrench.batched import single_threaded_blas

    with single_threaded_blas() if one_blas_thread else contextlib.nullcontext():
        return _run_decision_study(model, directions, U, force_scale, f0, decision, joint, study, rng_for,
                                   participants, n_threads, progress, on_participant, pset, abc, alg4_order)


def _run_decision_study(model, directions, U, force_scale, f0, decision, joint, study, rng_for, participants,
                        n_threads, progress, on_participant, pset, abc, alg4_order) -> pd.DataFrame:
    from neckstrength.wrench.batched import BasisCache

    directions = list(directions)
    names = list(model.muscle_names)
    c = study.cohort
    kinds = ["deficit"] * c.n_deficit + ["normal"] * c.n_normal
    todo = study.participants() if participants is None else list(participants)
    n_max = min(study.n_max, len(directions))
    base = np.array([n[:-2] if n.endswith(("-R", "-L")) else n for n in names])
    emg_mask = np.isin(base, list(study.emg_groups))
    deep_mask = emg_mask | np.isin(base, list(decision.group))
    gidx = decision.group_indices(names)
    rows = []
    t_start = time.time()
    cache = BasisCache()
    if "forces+postures" in study.protocols:
        from neckstrength.postures.model import pair_label

        if pset is None:
            raise ValueError("the forces+postures protocol needs the posture set (pset)")
        post = [p for p in study.postures if p in pset.postures]
        if post != list(study.postures) or "neutral" not in post:
            raise ValueError(f"forces+postures: postures {list(study.postures)} must include neutral and be among "
                             f"the posture set's {list(pset.postures)}")
        p_labels = [pair_label(p, n) for p in post for n in directions]
        p_post = [p for p in post for _ in directions]
        p_U = np.vstack([U] * len(post))
        p_fs = np.tile(np.asarray(force_scale, float), len(post))
    for i in todo:
        kind = kinds[i]
        f, forces, alpha = simulate_participant(model, U, force_scale, f0, decision.group, kind == "deficit", c,
                                                rng_for("truth", i), cache=cache)
        ratio = float(f[gidx].sum() / f0[gidx].sum())
        n_before = len(rows)
        for protocol in study.protocols:
            t0 = time.time()
            if protocol == "alg4":
                info = {"participant": i, "kind": kind, "true_ratio": ratio, "protocol": protocol}
                for t in study.alg4_tests:
                    rows.append({**info, **_alg4_row(model, directions, U, force_scale, f, forces, gidx, abc,
                                                     study.bootstrap_direction, t,
                                                     None if alg4_order is None else alg4_order(i))})
                if progress:
                    h = rows[-1]
                    progress(f"participant {i + 1}/{len(kinds)} ({kind}, group at {ratio:.0%}) alg4: f_c at "
                             f"{h['alg4_ratio']:.0%} of normal after {h['t']} tests, {h['alg4_iterations']} "
                             f"iterations; {time.time() - t0:.1f} s (total {time.time() - t_start:.0f} s)")
                continue
            mask = {"forces+emg": emg_mask, "forces+emg+deep": deep_mask}.get(protocol)
            labels, meas = directions, forces
            if protocol == "forces+postures":
                w, _, st = pset.wrenches(f[None], p_U, p_post)
                noise = np.exp(c.noise * rng_for("posture_noise", i).standard_normal(len(p_labels)))
                meas = np.where(np.array(p_post) == "neutral", np.tile(forces, len(study.postures)),
                                w[0] / p_fs * noise)
                labels = p_labels
                dec = DeficitDecision(model, p_labels, p_U, p_fs, f0, decision, joint, rng_for("candidates", i),
                                      n_threads=n_threads, cache=BasisCache(), pset=pset, test_postures=p_post)
            else:
                dec = DeficitDecision(model, directions, U, force_scale, f0, decision, joint,
                                      rng_for("candidates", i), n_threads=n_threads, cache=BasisCache())
            info = {"participant": i, "kind": kind, "true_ratio": ratio, "protocol": protocol}
            rows.append({**info, **dec.history[-1], "score": dec.history[-1]["log_bf"]})
            for _ in range(n_max):
                d, _ = dec.propose()
                k = labels.index(d)
                act = None
                if mask is not None:
                    lb, ub = np.zeros(len(names)), np.ones(len(names))
                    lb[mask] = np.clip(alpha[k][mask] - study.emg_band, 0, 1)
                    ub[mask] = np.clip(alpha[k][mask] + study.emg_band, 0, 1)
                    act = (lb, ub)
                dec.push(d, float(meas[k]), act)
                rows.append({**info, **dec.history[-1], "score": dec.history[-1]["log_bf"]})
            if progress:
                h = dec.history[-1]
                progress(f"participant {i + 1}/{len(kinds)} ({kind}, group at {ratio:.0%}) {protocol}: log BF "
                         f"{h['log_bf']:+.1f}, P(deficit) {h['p_deficit']:.2f} after {n_max} tests; "
                         f"{time.time() - t0:.1f} s (total {time.time() - t_start:.0f} s)")
        if on_participant:
            on_participant(pd.DataFrame(rows[n_before:]))
    return pd.DataFrame(rows)


def _alg4_row(model: ReducedModel, directions: list[str], U: np.ndarray, force_scale: np.ndarray, f: np.ndarray,
              forces: np.ndarray, gidx: np.ndarray, abc, bootstrap_direction: str, t: int,
              order: Sequence[str] | None) -> dict:
    """Algorithm 4 on the participant's forces after ``t`` tests (all directions, or the first ``t`` of ``order``
    with the bootstrap direction), read as a score of the group's estimate."""
    from neckstrength.abc.stage import run_alg4
    from neckstrength.estimation.datasets import Dataset

    if abc is None:
        raise ValueError("the alg4 protocol needs Algorithm 4's settings (abc)")
    t = min(int(t), len(directions))
    if t < len(directions):
        if order is None:
            raise ValueError(f"alg4 after {t} of {len(directions)} tests needs a test order (alg4_order)")
        used = list(order)[:t]
        if bootstrap_direction not in used:
            used = used[:-1] + [bootstrap_direction] if t > 1 else [bootstrap_direction]
    else:
        used = list(directions)
    k = [directions.index(x) for x in used]
    data = Dataset(name="study", directions=used, U=U[k], w_meas=np.asarray(forces)[k] * force_scale[k],
                   force_scale=np.asarray(force_scale)[k], f_true=f)
    t0 = time.time()
    # rng None: Algorithm 4 draws nothing; it would only subsample the stored candidates (not used here)
    run = run_alg4(model, data, abc, bootstrap_direction, None, 0, progress=lambda s: None)
    fc = run.estimate["f_c"].to_numpy(float)
    ratio = float(fc[gidx].sum() / model.strengths[gidx].sum())
    ratio_a = float(fc[gidx].sum() / run.f0[gidx].sum())
    return {"t": t, "direction": used[-1], "score": -np.log(ratio), "alg4_ratio": ratio, "alg4_ratio_scaled": ratio_a,
            "alg4_iterations": int(run.result.iterations), "alg4_converged": bool(run.result.converged),
            "alg4_seconds": time.time() - t0, "log_bf": np.nan, "p_deficit": np.nan, "decision": ""}


def _score(g: pd.DataFrame) -> pd.Series:
    """The ROC's score: ``score`` where the runs have it (alg4: -log f_c ratio), else log BF (older runs)."""
    if "score" in g.columns:
        return g["score"].where(g["score"].notna(), g["log_bf"])
    return g["log_bf"]


def _with_p(runs: pd.DataFrame) -> pd.DataFrame:
    """The runs of protocols with a probability (not alg4, a score only)."""
    return runs[runs["p_deficit"].notna()] if "p_deficit" in runs.columns else runs


def roc_auc(pos: np.ndarray, neg: np.ndarray) -> float:
    """Mann-Whitney estimate of P(score of a deficit > score of a normal), ties counted half."""
    pos, neg = np.asarray(pos, float), np.asarray(neg, float)
    gt = (pos[:, None] > neg[None, :]).mean()
    eq = (pos[:, None] == neg[None, :]).mean()
    return float(gt + 0.5 * eq)


def _auc_se(auc: float, n_pos: int, n_neg: int) -> float:
    """Hanley & McNeil (1982) standard error of the ROC area."""
    q1, q2 = auc / (2 - auc), 2 * auc ** 2 / (1 + auc)
    v = (auc * (1 - auc) + (n_pos - 1) * (q1 - auc ** 2) + (n_neg - 1) * (q2 - auc ** 2)) / (n_pos * n_neg)
    return float(np.sqrt(max(v, 0.0)))


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    d = 1 + z ** 2 / n
    c = (p + z ** 2 / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z ** 2 / (4 * n ** 2)) / d
    return float(max(0.0, c - h)), float(min(1.0, c + h))


def roc_curve(runs: pd.DataFrame, protocol: str, t: int) -> pd.DataFrame:
    """(false-alarm rate, sensitivity, threshold on the score) of the score (log BF; alg4: -log of the group's
    f_c ratio) after ``t`` tests."""
    g = runs[(runs["protocol"] == protocol) & (runs["t"] == t)]
    sc = _score(g)
    pos = sc[g["kind"] == "deficit"].to_numpy(float)
    neg = sc[g["kind"] == "normal"].to_numpy(float)
    if not len(pos) or not len(neg):              # no curve without both kinds (see missing_kind)
        return pd.DataFrame({"protocol": [], "t": [], "threshold_score": [], "false_alarm": [], "sensitivity": []})
    thr = np.r_[np.inf, np.sort(np.unique(np.r_[pos, neg]))[::-1], -np.inf]
    return pd.DataFrame({"protocol": protocol, "t": t, "threshold_score": thr,
                         "false_alarm": [(neg >= x).mean() for x in thr],
                         "sensitivity": [(pos >= x).mean() for x in thr]})


def rule_grid(runs: pd.DataFrame, p_decides: Sequence[float] = (0.9, 0.95, 0.99),
              min_tests: Sequence[int] = (1, 3, 5, 10)) -> pd.DataFrame:
    """:func:`sequential_table` for every combination of threshold and minimum number of tests (how the stopping
    rule's outcome depends on its two choices; read off the same runs)."""
    return pd.concat([sequential_table(runs, p, m)[1] for p in p_decides for m in min_tests], ignore_index=True)


def missing_kind(runs: pd.DataFrame, protocol: str) -> str:
    """'' when ``protocol``'s runs have deficit and normal participants, else a sentence saying which kind is
    missing (a study stopped before its first normal participant, or a cache of one kind)."""
    g = runs[runs["protocol"] == protocol]
    gone = [k for k in ("deficit", "normal") if k not in set(g["kind"])]
    if not gone:
        return ""
    return (f"{protocol}: no {' and no '.join(gone)} participants among its {g['participant'].nunique()} runs, so "
            "no ROC area or false-alarm threshold (a study stopped early? rerunning it resumes)")


def roc_table(runs: pd.DataFrame, checkpoints: Sequence[int], false_alarm: float = 0.05,
              p_decide: float = 0.95) -> pd.DataFrame:
    """Per protocol and t: ROC area (Hanley-McNeil se), the sensitivity at a false-alarm rate <= ``false_alarm``
    (the threshold chosen on these normals: optimistic by that choice), and the fixed rule P(deficit) >= p_decide.
    A protocol with participants of one kind only gets NaN for what needs both (ROC area, threshold) and the
    reason in ``note`` (:func:`missing_kind`), also given as a warning."""
    import warnings

    out = []
    groups = sorted(runs.groupby("protocol", sort=False), key=lambda pg: PROTOCOLS.index(pg[0]) if pg[0] in PROTOCOLS
                    else len(PROTOCOLS))                  # the study's order (forces first), not the rows'
    for protocol, gp in groups:
        note = missing_kind(runs, protocol)
        if note:
            warnings.warn(note, stacklevel=2)
        for t in checkpoints:
            g = gp[gp["t"] == t]
            if g.empty:
                continue
            sc = _score(g)
            pos = sc[g["kind"] == "deficit"].to_numpy(float)
            neg = sc[g["kind"] == "normal"].to_numpy(float)
            if len(pos) and len(neg):
                auc = roc_auc(pos, neg)
                curve = roc_curve(runs, protocol, t)
                ok = curve[curve["false_alarm"] <= false_alarm]
                best = ok.iloc[int(np.argmax(ok["sensitivity"].to_numpy()))]
            else:
                auc, best = np.nan, {"sensitivity": np.nan, "threshold_score": np.nan}
            pp = g.loc[g["kind"] == "deficit", "p_deficit"].to_numpy(float)
            pn = g.loc[g["kind"] == "normal", "p_deficit"].to_numpy(float)
            pp, pn = pp[np.isfinite(pp)], pn[np.isfinite(pn)]          # alg4: a score, no probability
            k_s, k_f = int((pp >= p_decide).sum()), int((pn >= p_decide).sum())
            s_lo, s_hi = _wilson(k_s, len(pp))
            f_lo, f_hi = _wilson(k_f, len(pn))
            out.append({"protocol": protocol, "t": t, "n_deficit": len(pos), "n_normal": len(neg), "auc": auc,
                        "auc_se": _auc_se(auc, len(pos), len(neg)) if np.isfinite(auc) else np.nan,
                        f"sensitivity_at_fa{false_alarm:g}": float(best["sensitivity"]),
                        "threshold_score": float(best["threshold_score"]),
                        f"rule_sensitivity_p{p_decide:g}": k_s / len(pp) if len(pp) else np.nan,
                        "rule_sensitivity_ci95_low": s_lo, "rule_sensitivity_ci95_high": s_hi,
                        f"rule_false_alarm_p{p_decide:g}": k_f / len(pn) if len(pn) else np.nan,
                        "rule_false_alarm_ci95_low": f_lo, "rule_false_alarm_ci95_high": f_hi, "note": note})
    out = pd.DataFrame(out)
    return out.drop(columns="note") if "note" in out and not out["note"].astype(bool).any() else out


def sequential_table(runs: pd.DataFrame, p_decide: float = 0.95,
                     min_tests: int = 1) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The stopping rule: per run the first t >= ``min_tests`` at which P(deficit) >= p_decide (deficit) or <=
    1 - p_decide (no deficit), else undecided after the last test; per protocol and kind the shares and the median
    tests. The test order does not depend on the rule, so any rule can be read off the same runs."""
    per = []
    for (i, protocol), g in _with_p(runs).groupby(["participant", "protocol"], sort=False):
        g = g.sort_values("t")
        g1 = g[g["t"] >= max(1, min_tests)]
        hit = g1[(g1["p_deficit"] >= p_decide) | (g1["p_deficit"] <= 1 - p_decide)]
        if len(hit):
            r = hit.iloc[0]
            dec, t = ("deficit" if r["p_deficit"] >= p_decide else "no deficit"), int(r["t"])
        else:
            dec, t = "undecided", int(g["t"].max())
        per.append({"participant": i, "protocol": protocol, "kind": g["kind"].iloc[0],
                    "true_ratio": g["true_ratio"].iloc[0], "decision": dec, "tests": t})
    per = pd.DataFrame(per)
    if per.empty:                                 # only protocols without a probability (alg4)
        return per, pd.DataFrame()
    out = []
    for (protocol, kind), g in per.groupby(["protocol", "kind"], sort=False):
        n = len(g)
        row = {"protocol": protocol, "kind": kind, "p_decide": p_decide, "min_tests": min_tests, "n": n}
        for d in ("deficit", "no deficit", "undecided"):
            k = int((g["decision"] == d).sum())
            lo, hi = _wilson(k, n)
            row[f"share_{d.replace(' ', '_')}"] = k / n
            row[f"share_{d.replace(' ', '_')}_ci95"] = f"{lo:.2f}-{hi:.2f}"
        dd = g[g["decision"] != "undecided"]["tests"]
        row["median_tests_to_decision"] = float(dd.median()) if len(dd) else float("nan")
        out.append(row)
    return per, pd.DataFrame(out)


def reliability_table(runs: pd.DataFrame, checkpoints: Sequence[int],
                      edges: Sequence[float] = (0, 0.05, 0.2, 0.4, 0.6, 0.8, 0.95, 1.0)) -> pd.DataFrame:
    """Of the (participant, t) pairs given P(deficit) in a bin, the share with the deficit, with its 95% interval
    (Jeffreys), per protocol; pooled over the checkpoints. Calibrated where the mean P lies within the interval."""
    out = []
    e = np.asarray(edges, float)
    for protocol, gp in _with_p(runs).groupby("protocol", sort=False):
        g = gp[gp["t"].isin(list(checkpoints))]
        p = g["p_deficit"].to_numpy(float)
        y = (g["kind"] == "deficit").to_numpy()
        b = np.clip(np.searchsorted(e, p, side="right") - 1, 0, len(e) - 2)
        for k in range(len(e) - 1):
            sel = b == k
            n = int(sel.sum())
            if not n:
                continue
            hits = int(y[sel].sum())
            lo, hi = beta_dist.ppf([0.025, 0.975], hits + 0.5, n - hits + 0.5)
            lo, hi = (0.0 if hits == 0 else lo), (1.0 if hits == n else hi)     # Brown, Cai & DasGupta 2001
            mean_p = float(p[sel].mean())
            out.append({"protocol": protocol, "bin_low": e[k], "bin_high": e[k + 1], "n": n,
                        "mean_p_deficit": mean_p, "share_with_deficit": hits / n, "ci95_low": float(lo),
                        "ci95_high": float(hi), "within_ci": bool(lo <= mean_p <= hi)})
    return pd.DataFrame(out)


def _platt_features(x: np.ndarray) -> np.ndarray:
    return np.c_[x, np.ones_like(x), np.tanh(x / 2)]


def _fit_platt(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Maximum-likelihood ``logit P(y = 1) = a x + b + c tanh(x / 2)`` (Newton's method): Platt scaling with a bend
    near x = 0, where the study's Bayes factor is flattest (docs/clinician.md). Monotone in ``x`` is required
    (``a > 0`` and ``a + c / 2 > 0``); a fit that is not falls back to plain Platt scaling (``c = 0``)."""
    def newton(X):
        th = np.zeros(X.shape[1])
        for _ in range(100):
            z = np.clip(X @ th, -500, 500)
            p = 1.0 / (1.0 + np.exp(-z))
            # a weak ridge (0.01, against complete separation in small studies; negligible at the study's size)
            H = (X * (p * (1 - p))[:, None]).T @ X + 0.01 * np.eye(X.shape[1])
            step = np.linalg.solve(H, X.T @ (y - p) - 0.01 * th)
            th = th + step
            if np.abs(step).max() < 1e-10:
                break
        return th

    a, b, c = newton(_platt_features(x))
    if not (a > 0 and a + c / 2 > 0):
        a, b = newton(_platt_features(x)[:, :2])
        c = 0.0
    return float(a), float(b), float(c)


def recalibrate(runs: pd.DataFrame, decision, model_name: str, n_directions: int, checkpoints: Sequence[int],
                protocol: str = "forces", false_alarm: float = 0.05,
                edges: Sequence[float] = (0, 0.05, 0.2, 0.4, 0.6, 0.8, 0.95, 1.0),
                source: str = "") -> tuple:
    """Recalibrate the Bayes factor on the study's patients (:class:`~neckstrength.sequential.decision.
    DecisionCalibration`: Platt scaling of log BF with a bend, pooled over every t >= the rule's ``min_tests``) and check it
    held out: two folds by participant parity, each fold's probabilities from the map fitted on the other
    (cross-fitting). Returns ``(calibration, reliability, rule)``:

    - ``reliability``: :func:`reliability_table` of the cross-fitted probabilities at the checkpoints (the
      calibration's check: bins whose mean P lies within the Jeffreys 95% interval of the share with the deficit;
      the pairs (participant, t) of one participant are not independent, so the intervals are somewhat narrow);
    - ``rule``: per checkpoint, held out, the recalibrated rule P >= p_decide (sensitivity, false alarms) and a
      threshold on log BF chosen on the other fold's normals for a false-alarm rate <= ``false_alarm`` (its
      sensitivity and false-alarm rate on the held-out fold: not optimistic, unlike :func:`roc_table`'s).
    """
    from neckstrength.sequential.decision import DecisionCalibration

    t_from = min(decision.min_tests, max(checkpoints))       # a short study (CI) pools what it has
    g = runs[(runs["protocol"] == protocol) & (runs["t"] >= t_from)].copy()
    if g.empty:
        raise ValueError(f"recalibrate: no runs of protocol {protocol!r} with t >= {t_from}")
    y = (g["kind"] == "deficit").to_numpy(float)
    x = g["log_bf"].to_numpy(float)
    share = float(runs.drop_duplicates("participant")["kind"].eq("deficit").mean())
    fold = (g["participant"].to_numpy() % 2).astype(int)
    pc = np.empty(len(g))
    for f in (0, 1):
        th = np.array(_fit_platt(x[fold != f], y[fold != f]))
        pc[fold == f] = 1.0 / (1.0 + np.exp(-np.clip(_platt_features(x[fold == f]) @ th, -500, 500)))
    g["p_deficit"] = pc
    g["protocol"] = f"{protocol} (recalibrated, cross-fitted)"
    rel = reliability_table(g, checkpoints, edges)
    a, b, c = _fit_platt(x, y)
    check = (f"cross-fitted reliability (2 folds by participant, t = {', '.join(map(str, checkpoints))}): "
             f"{int(rel['within_ci'].sum())} of {len(rel)} bins within the 95% interval")
    cal = DecisionCalibration(model=model_name, group=tuple(decision.group),
                              deficit_range=tuple(decision.deficit_range), population_sd=decision.population_sd,
                              noise=decision.noise, n_candidates=decision.n_candidates, sampler=decision.sampler,
                              n_directions=int(n_directions), cohort_share=share,
                              n_patients=int(runs["participant"].nunique()), t_from=int(t_from), slope=a,
                              intercept=b, bend=c, check=check,
                              source=source)
    rows = []
    for t in checkpoints:
        gt = g[g["t"] == t]
        if gt.empty:
            continue
        yt = (gt["kind"] == "deficit").to_numpy()
        ft = (gt["participant"].to_numpy() % 2).astype(int)
        lb = gt["log_bf"].to_numpy(float)
        hit_rule = gt["p_deficit"].to_numpy(float) >= decision.p_decide
        hit_thr = np.zeros(len(gt), bool)
        thr = []
        for f in (0, 1):
            neg = lb[(ft != f) & ~yt]
            c = float(np.quantile(neg, 1 - false_alarm, method="higher")) if len(neg) else np.inf
            thr.append(c)
            hit_thr[ft == f] = lb[ft == f] > c
        row = {"protocol": protocol, "t": t, "n_deficit": int(yt.sum()), "n_normal": int((~yt).sum())}
        for name, hit in ((f"rule_p{decision.p_decide:g}", hit_rule), (f"threshold_fa{false_alarm:g}", hit_thr)):
            ks, kf = int(hit[yt].sum()), int(hit[~yt].sum())
            s_lo, s_hi = _wilson(ks, int(yt.sum()))
            f_lo, f_hi = _wilson(kf, int((~yt).sum()))
            row.update({f"{name}_sensitivity": ks / max(1, yt.sum()), f"{name}_sensitivity_ci95":
                        f"{s_lo:.2f}-{s_hi:.2f}", f"{name}_false_alarm": kf / max(1, (~yt).sum()),
                        f"{name}_false_alarm_ci95": f"{f_lo:.2f}-{f_hi:.2f}"})
        row["threshold_log_bf_folds"] = " / ".join(f"{c:+.2f}" for c in thr)
        rows.append(row)
    return cal, rel, pd.DataFrame(rows)


def _guard_stats(piv: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Per column (t) of a participants x t table of best-fit RMS: the median of log RMS and its MAD-based sd."""
    y = np.log(piv.to_numpy(float))
    med = np.median(y, axis=0)
    sd = 1.4826 * np.median(np.abs(y - med), axis=0)
    return med, np.maximum(sd, 1e-6)


def _guard_max(piv: pd.DataFrame, med: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """Per participant the largest standardised log best fit over the table's tests."""
    return ((np.log(piv.to_numpy(float)) - med) / sd).max(axis=1)


def fit_misfit_guard(runs: pd.DataFrame, decision, model_name: str, n_directions: int, level: float,
                     protocol: str = "forces", source: str = "") -> tuple:
    """The calibrated misfit guard (:class:`~neckstrength.sequential.decision.MisfitGuard`) from the study's runs of
    ``protocol`` (the model's own patients), and its held-out check: two folds by participant parity, each fold's
    patients flagged (at any t >= ``t_from``) by the guard fitted on the other. Returns ``(guard, check)``, the
    check a table with, per level (``level`` and 0.01 / 0.05 / 0.1 for comparison), the held-out share of the
    model's patients flagged (Wilson 95%) and the fitted factor."""
    from neckstrength.sequential.decision import MisfitGuard

    g = runs[(runs["protocol"] == protocol) & (runs["t"] >= 1)]
    if g.empty or "misfit_rms" not in g.columns or g["misfit_rms"].isna().all():
        raise ValueError(f"fit_misfit_guard: no best-fit RMS (misfit_rms) in the runs of protocol {protocol!r}")
    t_max = int(g["t"].max())
    t_from = min(decision.min_tests, t_max)
    piv = g.pivot_table(index="participant", columns="t", values="misfit_rms", aggfunc="first")
    if list(piv.columns) != list(range(1, t_max + 1)) or piv.isna().any().any():
        raise ValueError("fit_misfit_guard: every run needs every t from 1 to the last")
    piv = piv[list(range(t_from, t_max + 1))]
    med, sd = _guard_stats(piv)
    rows = []
    factor = float("nan")
    for lv in dict.fromkeys((level, 0.01, 0.05, 0.1)):
        fac = float(np.quantile(_guard_max(piv, med, sd), 1 - lv, method="higher"))
        if lv == level:
            factor = fac
        part = piv.index.to_numpy() % 2
        flagged = np.zeros(len(piv), bool)
        for f in (0, 1):
            fit, test = piv[part != f], piv[part == f]
            m, s = _guard_stats(fit)
            c = float(np.quantile(_guard_max(fit, m, s), 1 - lv, method="higher"))
            flagged[part == f] = _guard_max(test, m, s) > c
        k = int(flagged.sum())
        lo, hi = _wilson(k, len(flagged))
        rows.append({"level": lv, "factor": fac, "n_patients": len(flagged), "held_out_flagged": k,
                     "held_out_share": k / len(flagged), "held_out_ci95": f"{lo:.2f}-{hi:.2f}",
                     "t_from": t_from, "t_max": t_max})
    check = pd.DataFrame(rows)
    r0 = check.iloc[0]
    guard = MisfitGuard(model=model_name, noise=decision.noise, n_candidates=decision.n_candidates,
                        sampler=decision.sampler, n_directions=int(n_directions), level=float(level),
                        t_from=int(t_from), factor=factor, log_median=tuple(float(x) for x in med),
                        log_sd=tuple(float(x) for x in sd), n_patients=int(len(piv)),
                        check=(f"held out (2 folds by participant): {int(r0['held_out_flagged'])} of "
                               f"{int(r0['n_patients'])} of the model's own patients flagged "
                               f"({r0['held_out_share']:.0%}, 95% {r0['held_out_ci95']})"),
                        source=source)
    return guard, check


def misfit_flags(runs: pd.DataFrame, guard, min_tests: int) -> pd.DataFrame:
    """Per participant and protocol of ``runs``: flagged by ``guard`` (:class:`~neckstrength.sequential.decision.
    MisfitGuard`) at some t >= max(``min_tests``, its ``t_from``), the first such t, the largest best-fit RMS over
    the guard's threshold. The guard is a function of the runs' best-fit RMS and t, so any runs (another truth's)
    can be read with it afterwards."""
    out = []
    t0 = max(min_tests, guard.t_from)
    for (i, protocol), g in _with_p(runs).groupby(["participant", "protocol"], sort=False):
        kind = g["kind"].iloc[0]
        g = g[(g["t"] >= t0) & (g["t"] <= guard.t_max)].sort_values("t")
        thr = np.array([guard.threshold(int(t)) for t in g["t"]])
        r = g["misfit_rms"].to_numpy(float) / thr
        hit = np.flatnonzero(r > 1)
        out.append({"participant": i, "protocol": protocol, "kind": kind,
                    "flagged": bool(len(hit)), "first_t": int(g["t"].iloc[hit[0]]) if len(hit) else np.nan,
                    "max_over_threshold": float(np.nanmax(r)) if len(r) else np.nan})
    return pd.DataFrame(out)


def misfit_flag_table(runs: pd.DataFrame, guard, min_tests: int) -> pd.DataFrame:
    """Per protocol (truth) and kind: the share of patients the guard flags (Wilson 95%)."""
    per = misfit_flags(runs, guard, min_tests)
    out = []
    for (protocol, kind), g in per.groupby(["protocol", "kind"], sort=False):
        k, n = int(g["flagged"].sum()), len(g)
        lo, hi = _wilson(k, n)
        out.append({"protocol": protocol, "kind": kind, "n": n, "flagged": k, "share_flagged": k / n,
                    "ci95": f"{lo:.2f}-{hi:.2f}", "median_first_t": float(g["first_t"].median())})
    return pd.DataFrame(out)
