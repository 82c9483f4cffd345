"""Chapter 6: sequential strength estimation with entropy-reducing test selection (Algorithms 7-9).

Pieces (thesis names, equation numbers in the docstrings):

- :func:`scaled_baseline`, :func:`sample_prior`  prior ``N(f_0, (0.3 f_0)^2)``, ``f_0 = a f'_base`` with ``a``
  the average over the test directions of Eq. 5.3's scalar (Sec. 6.5.1); ``N_F`` candidates drawn once.
- :class:`SimulatedSet`      the "general simulated data set" ``{w_sim, alpha_sim}_{i,k} = M(f_k, u_i)`` of
  Algorithm 7, precomputed once, with the tables that make Algorithm 9 cheap (below).
- :func:`data_likelihood`   Algorithm 8: Eq. 6.4 discrepancy (:func:`neckstrength.abc.data_discrepancy`),
  rejection below the q-th percentile, Eq. 6.5 activation-weighted per-muscle likelihood over the f_j domain.
- :func:`posterior_from_loglik`, :func:`pdf_moments`, :func:`pdf_entropy`  posterior PDFs, E, Var, Eq. 6.3.
- :func:`expected_entropy_reduction`  Eq. 6.6 (Algorithm 9's forward simulation) and
  :func:`select_direction` Eqs. 6.7/6.8 (muscle priorities gamma).
- :class:`SequentialState`  Algorithm 7 one step at a time (``propose``, ``update``, ``undo``, ``save``/``load``)
  for the pipeline and for a clinician-in-the-loop command; :func:`run_sequence` is the full loop.
- :func:`subset_table`, :func:`order_entropies`  exact permutation analysis: with the candidates drawn once
  the posterior after t tests depends only on the *set* of tested directions, so the 2^K subsets give the
  entropy of every one of the K! orders.
- :func:`stop_iteration`, :func:`stop_by_expected_gain`  when the estimate stops changing.

Representation (the thesis does not state it; docs/chapter6.md). Eq. 6.5 is a likelihood "over the domain f,
for each muscle j": ``L_j(b) = sum_{k in F', f_kj in bin b} alpha_jk d_k``. Each muscle's posterior is a PDF
on a fixed grid of ``n_bins`` bins spanning ``f_0 +- bin_range_sd * sigma_0`` and
``p_j(f | tests) ∝ p_j^0(f) prod_t L_{j,t}(f)`` (the prior PDF is the candidates' histogram). Literal Eq. 6.5
is a *sum* over the prior sample, so each factor carries the prior density once more
(``likelihood='sum'``, default, as printed); ``likelihood='mean'`` divides by the candidates per bin (a
likelihood estimate proper). Entropies are differential entropies of the histogram PDFs in nats
(``-sum p log p + log h``), so they are comparable across bin settings; E and Var are computed from the same
PDFs. Two guards the thesis does not mention: a test is uninformative about muscle j (factor 1) when the
d-weighted mean activation of j among the accepted candidates is below ``alpha_min`` (Chapter 5's "zero total
weight -> uniform" rule, extended to near-zero weights that would otherwise rest on a handful of candidates),
and every factor is floored at ``likelihood_floor`` times its maximum so that tests whose likelihoods have
disjoint supports do not annihilate the posterior. Both depend on the test only, so the posterior still
depends only on the set of tests.

Fast Algorithm 9. The forward-simulated likelihood of a simulated measurement ``w^s`` in direction i needs
``sum_k alpha_kij d_k(w^s) acc_k(w^s)`` per muscle and f-bin. ``d_k`` and ``acc_k`` depend on candidate k only
through ``w_{k,i}``, so the candidates are binned once on a fine geometric grid of ``w`` (``n_wbins`` bins,
relative width ~0.5%) and ``A_i[v, j, b] = sum_{k: w_ki in v, f_kj in b} alpha_kij`` is tabulated with the
general data set; rejection works on the binned counts, and the accepted bins of all N_S draws form a sparse
matrix that multiplies ``A_i``, so a proposal costs the same for any N_F. The exact per-candidate computation
(:func:`expected_entropy_reduction` with ``exact=True``) is kept as the reference.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.estimation.datasets import Dataset
from neckstrength.estimation.discrepancy import composite_score, data_discrepancy
from neckstrength.estimation.scaling import bootstrap_prior
from neckstrength.model.reduction import ReducedModel
from neckstrength.wrench import solve
from neckstrength.wrench.problem import STATUS_CODES

_OPT = {v: k for k, v in STATUS_CODES.items()}["optimal"]


@dataclass(frozen=True)
class SequentialSettings:
    """Algorithms 7-9 settings; thesis values where it states them (Sec. 6.5.1), else documented choices."""

    n_candidates: int = 500_000     # N_F (Sec. 6.5.1)
    n_sim: int = 100                # N_S (Sec. 6.5.1; 50 in the text of Fig. 6.7)
    prior_sd_rel: float = 0.3       # p(f) = N(f_0, v_0), "v_0 = 0.3 f_0": read as sd = 0.3 f_0 (Chapter 5's sigma_0)
    epsilon: float = 3.0            # Eq. 6.4 (= Eq. 5.5, Chapter 5's value)
    q: float = 90.0                 # rejection percentile (not stated; Chapter 5's)
    n_bins: int = 50                # per-muscle PDF grid (not stated)
    bin_range_sd: float = 4.0       # grid spans f_0 +- bin_range_sd * sigma_0 (clipped at 0)
    n_wbins: int = 512              # fast Algorithm 9: geometric grid of simulated wrenches per direction
    alpha_min: float = 0.02         # a test informs muscle j only if its mean accepted activation >= alpha_min
    likelihood: str = "sum"         # 'sum' = Eq. 6.5 as printed; 'mean' = per-bin mean (density-corrected)
    likelihood_floor: float = 1e-6  # each factor floored at this fraction of its maximum
    predictive: str = "prior"       # Algorithm 9: w^s drawn from the general set ('prior', as printed) or
    #                                 weighted by the current (mean-field) posterior ('posterior')
    emg_band: float = 0.05          # activation bounds +- band around a measured activation (update())

    def __post_init__(self):
        if self.likelihood not in ("sum", "mean"):
            raise ValueError(f"likelihood must be 'sum' or 'mean', not {self.likelihood!r}")
        if self.predictive not in ("prior", "posterior"):
            raise ValueError(f"predictive must be 'prior' or 'posterior', not {self.predictive!r}")
        if not 0 <= self.q < 100:
            raise ValueError("q must be in [0, 100)")


def scaled_baseline(model: ReducedModel, data: Dataset) -> tuple[np.ndarray, float, np.ndarray]:
    """``f_0 = a f'_base`` with ``a`` the average of Eq. 5.3's per-direction scalars (Sec. 6.5.1).

    Returns ``f_0`` (m,), ``a`` and the per-direction scalars (K,).
    """
    a_i = np.array([bootstrap_prior(model, data, name)[1] for name in data.directions])
    a = float(a_i.mean())
    return a * model.strengths, a, a_i


def producible_truth(draw_and_solve: Callable[[], tuple], what: str, tries: int = 100) -> tuple:
    """Redraw a simulated participant until its maximum force is optimal (producible) in every direction.

    ``draw_and_solve()`` draws a truth from its own random stream and returns a tuple whose last element is the
    solver's status row (K,) for it; the first draw whose statuses are all optimal is returned whole. Raises
    ``RuntimeError`` naming ``what`` after ``tries`` draws."""
    for _ in range(tries):
        out = draw_and_solve()
        if np.all(np.asarray(out[-1]) == _OPT):
            return out
    raise RuntimeError(f"{what}: no producible truth in {tries} draws")


def sample_prior(f0: np.ndarray, sd_rel: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``N_F`` candidates from ``N(f_0, (sd_rel f_0)^2)`` truncated to positive strengths (redrawn)."""
    f0 = np.asarray(f0, float)
    F = f0 * (1.0 + sd_rel * rng.standard_normal((n, len(f0))))
    bad = F <= 0
    while bad.any():
        F[bad] = (f0 * (1.0 + sd_rel * rng.standard_normal(F.shape)))[bad]
        bad = F <= 0
    return F


@dataclass(frozen=True)
class StrengthGrid:
    """Per-muscle bins of the posterior PDFs: ``edges`` (m, n_bins + 1)."""

    edges: np.ndarray

    @classmethod
    def around(cls, f0: np.ndarray, sd_rel: float, n_bins: int, range_sd: float) -> "StrengthGrid":
        f0 = np.asarray(f0, float)
        lo = np.maximum(0.0, f0 * (1.0 - range_sd * sd_rel))
        hi = f0 * (1.0 + range_sd * sd_rel)
        return cls(np.linspace(lo, hi, n_bins + 1).T.copy())

    @property
    def m(self) -> int:
        return self.edges.shape[0]

    @property
    def n_bins(self) -> int:
        return self.edges.shape[1] - 1

    @property
    def centres(self) -> np.ndarray:
        return 0.5 * (self.edges[:, 1:] + self.edges[:, :-1])

    @property
    def widths(self) -> np.ndarray:
        return self.edges[:, 1] - self.edges[:, 0]

    def index(self, F: np.ndarray) -> np.ndarray:
        """Bin of every candidate and muscle (N, m); values outside the grid go to the edge bins."""
        F = np.atleast_2d(F)
        out = np.empty(F.shape, dtype=np.int16)
        for j in range(self.m):
            out[:, j] = np.clip(np.searchsorted(self.edges[j], F[:, j], side="right") - 1, 0, self.n_bins - 1)
        return out


@dataclass
class SimulatedSet:
    """Candidates ``F`` (drawn once) with the general simulated data set and Algorithm 9's tables.

    ``w`` (N, K) max wrenches (0 where not producible); ``iw`` (N,) importance weights (1 for prior draws);
    ``fbin`` (N, m) strength-bin index; ``wedges`` (K, n_wbins + 1) geometric wrench grid per direction;
    ``wbin`` (N, K) wrench-bin index (0 = zero wrench, 1..n_wbins); ``wcount`` (K, n_wbins + 1) summed
    ``iw`` per wrench bin; ``A`` (K, n_wbins + 1, m, n_bins) summed ``iw * alpha``; ``alpha`` (N, K, m) kept
    only when asked (tests, small N). ``prior_pdf`` (m, n_bins) is the candidates' histogram.
    """

    directions: list[str]
    U: np.ndarray
    F: np.ndarray
    iw: np.ndarray
    grid: StrengthGrid
    fbin: np.ndarray
    w: np.ndarray
    wedges: np.ndarray
    wbin: np.ndarray
    wcount: np.ndarray
    A: np.ndarray
    prior_pdf: np.ndarray
    alpha: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def N(self) -> int:
        return self.F.shape[0]

    @property
    def uniform_weights(self) -> bool:
        """All importance weights equal (candidates drawn from the prior): Algorithm 9 draws uniformly."""
        if "_uniform" not in self.__dict__:
            self.__dict__["_uniform"] = bool(np.all(self.iw == self.iw[0]))
        return self.__dict__["_uniform"]

    @property
    def activation_sums(self) -> np.ndarray:
        """``sum_b A[i, v, j, b]`` (K, n_wbins + 1, m): summed activation per wrench bin (cached)."""
        if "_asum" not in self.__dict__:
            self.__dict__["_asum"] = self.A.sum(axis=3, dtype=np.float64)
        return self.__dict__["_asum"]

    @property
    def K(self) -> int:
        return len(self.directions)

    @property
    def m(self) -> int:
        return self.F.shape[1]

    @classmethod
    def build(cls, model: ReducedModel, directions: Sequence[str], U: np.ndarray, F: np.ndarray,
              grids: Sequence[StrengthGrid], n_wbins: int, iw: np.ndarray | None = None, keep_alpha: bool = False,
              chunk: int = 65536, n_threads: int = 1, cache=None, meta: dict | None = None,
              progress: Callable[[str], None] | None = None) -> list["SimulatedSet"]:
        """The general simulated data set for candidates ``F`` and Algorithm 9's tables, one set per grid.

        One solve per candidate and direction (:func:`neckstrength.wrench.solve`: the wrench and the optimal
        activations together), direction by direction (``n_threads`` directions at a time): once all the
        wrenches of a direction are known its geometric wrench grid is fixed, and its activations go straight
        into ``A`` (double precision sums, stored in single precision); the (N, K, m) activations are held
        only with ``keep_alpha``.
        """
        import time

        from neckstrength.wrench import BasisCache

        t0 = time.time()
        cache = BasisCache() if cache is None else cache
        F = np.asarray(F, float)
        U = np.asarray(U, float)
        N, m = F.shape
        K = U.shape[0]
        iw = np.ones(N) if iw is None else np.asarray(iw, float)
        fbins = [g.index(F) for g in grids]
        As = [np.zeros((K, n_wbins + 1, m, g.n_bins)) for g in grids]
        w = np.zeros((N, K))
        status = np.zeros((N, K), dtype=np.int8)
        wedges = np.zeros((K, n_wbins + 1))
        wbin = np.zeros((N, K), dtype=np.int16)
        wcount = np.zeros((K, n_wbins + 1))
        alpha_all = np.zeros((N, K, m), dtype=np.float32) if keep_alpha else None
        t_tab = 0.0
        step = max(1, int(n_threads))
        for i0 in range(0, K, step):
            ii = list(range(i0, min(K, i0 + step)))
            wi, a, st = solve(model, F, U[ii], chunk_size=chunk, cache=cache, return_alpha=True, n_threads=n_threads)
            t = time.time()
            ok = st == _OPT
            a[~ok] = 0.0
            if np.isnan(a).any():
                np.nan_to_num(a, copy=False, nan=0.0)
            for c, i in enumerate(ii):
                w[:, i] = np.where(ok[:, c], wi[:, c], 0.0)
                status[:, i] = st[:, c]
                pos = w[:, i] > 0
                if pos.any():
                    lo, hi = w[pos, i].min() * (1 - 1e-9), w[pos, i].max() * (1 + 1e-9)
                    wedges[i] = np.geomspace(lo, hi if hi > lo else lo * 1.001, n_wbins + 1)
                else:
                    wedges[i] = np.geomspace(1.0, 2.0, n_wbins + 1)
                v = np.clip(np.searchsorted(wedges[i], w[:, i], side="right"), 1, n_wbins)
                v[~pos] = 0
                wbin[:, i] = v
                wcount[i] = np.bincount(v, weights=iw, minlength=n_wbins + 1)
                for g, fb, A in zip(grids, fbins, As):
                    _accumulate_activations(A[i], a[:, c, :], v, fb, iw, chunk)
                if keep_alpha:
                    alpha_all[:, i] = a[:, c, :]
            del a
            t_tab += time.time() - t
            if progress and K > step:
                progress(f"[{model.name}] general simulated data set: {ii[-1] + 1} of {K} directions "
                         f"({time.time() - t0:.0f} s)")
        t1 = time.time() - t_tab
        meta = dict(meta or {})
        meta.update({"model": model.name, "n_candidates": int(N), "n_not_producible": int((status != _OPT).sum()),
                     "seconds_wrench": t1 - t0, "seconds_activation": t_tab})
        # seconds_wrench: the solves (wrenches and activations); seconds_activation: the tables
        if progress:
            progress(f"[{model.name}] general simulated data set: {N} candidates x {K} directions; solves "
                     f"{t1 - t0:.1f} s, tables {t_tab:.1f} s "
                     f"({meta['n_not_producible']} not producible)")
        out = []
        for g, fb, A in zip(grids, fbins, As):
            prior = np.stack([np.bincount(fb[:, j], weights=iw, minlength=g.n_bins) for j in range(m)])
            prior /= prior.sum(axis=1, keepdims=True)
            out.append(cls(list(directions), U, F, iw, g, fb, w, wedges, wbin, wcount, A.astype(np.float32), prior,
                           alpha_all, dict(meta)))
        return out

    def save(self, path: str | Path) -> None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        arrays = {k: getattr(self, k) for k in ("U", "F", "iw", "fbin", "w", "wedges", "wbin", "wcount", "A",
                                                 "prior_pdf")}
        arrays["edges"] = self.grid.edges
        if self.alpha is not None:
            arrays["alpha"] = self.alpha
        np.savez(tmp, directions=np.array(self.directions), meta=json.dumps(self.meta), **arrays)
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path) -> "SimulatedSet":
        z = np.load(path, allow_pickle=False)
        return cls([str(x) for x in z["directions"]], z["U"], z["F"], z["iw"], StrengthGrid(z["edges"]), z["fbin"],
                   z["w"], z["wedges"], z["wbin"], z["wcount"], z["A"], z["prior_pdf"],
                   z["alpha"] if "alpha" in z.files else None, json.loads(str(z["meta"])))


def _accumulate_activations(A: np.ndarray, alpha: np.ndarray, wbin: np.ndarray, fbin: np.ndarray, iw: np.ndarray,
                            chunk: int) -> None:
    """One direction: ``A[v, j, b] += sum_{k: wbin_k = v, fbin_kj = b} iw_k alpha_kj`` (double precision sums)."""
    if _accumulate_compiled is not None:
        _accumulate_compiled(A, np.ascontiguousarray(alpha), np.ascontiguousarray(wbin), np.ascontiguousarray(fbin),
                             np.ascontiguousarray(iw, dtype=float))
        return
    nv, m, nb = A.shape
    cols = np.arange(m)[None, :] * nb
    for s in range(0, alpha.shape[0], chunk):
        e = min(alpha.shape[0], s + chunk)
        idx = wbin[s:e, None].astype(np.int64) * (m * nb) + (fbin[s:e] + cols)
        A += np.bincount(idx.ravel(), weights=(iw[s:e, None] * alpha[s:e]).ravel(),
                         minlength=nv * m * nb).reshape(nv, m, nb)


try:  # compiled accumulation (numba, a dependency of the solver); the bincount loop above otherwise
    from numba import njit

    @njit(cache=True, nogil=True)
    def _accumulate_compiled(A, alpha, wbin, fbin, iw):  # pragma: no cover - compiled
        for k in range(alpha.shape[0]):
            v = wbin[k]
            for j in range(alpha.shape[1]):
                a = alpha[k, j]
                if a != 0.0:
                    A[v, j, fbin[k, j]] += iw[k] * a
except ImportError:  # pragma: no cover
    _accumulate_compiled = None


def _weighted_threshold(d: np.ndarray, iw: np.ndarray, q: float) -> float:
    """q-th percentile of ``d`` (weighted by ``iw``; numpy's percentile when all weights are 1)."""
    if np.all(iw == iw[0]):
        return float(np.percentile(d, q))
    o = np.argsort(d)
    c = np.cumsum(iw[o])
    return float(d[o[min(np.searchsorted(c, q / 100.0 * c[-1]), len(o) - 1)]])


def data_likelihood(w_sim: np.ndarray, alpha_sim: np.ndarray | Callable[[np.ndarray], np.ndarray],
                    w_meas: float, fbin: np.ndarray, iw: np.ndarray, n_bins: int,
                    settings: SequentialSettings) -> tuple[np.ndarray, np.ndarray, dict]:
    """Algorithm 8 for one measurement: per-muscle likelihood over the strength bins.

    (1) Eq. 6.4 ``d_k = exp(-(eps delta_k)^2)`` (:func:`neckstrength.abc.data_discrepancy`); (2) keep the
    candidates with ``d_k >=`` the q-th percentile; (3) Eq. 6.5 ``L_j(b) = sum_{k in F', f_kj in b} alpha_jk d_k``
    (times the importance weight; divided by the candidates per bin for ``likelihood='mean'``).
    ``alpha_sim``: (N, m) activations, or a function giving them for an index array of accepted candidates.
    Returns ``L`` (m, n_bins), ``informative`` (m,) bool (mean accepted activation >= ``alpha_min``) and
    diagnostics.
    """
    N, m = fbin.shape
    d = data_discrepancy(np.asarray(w_sim, float), float(w_meas), settings.epsilon)
    thr = _weighted_threshold(d, iw, settings.q)
    acc = np.nonzero(d >= thr)[0]
    a = alpha_sim(acc) if callable(alpha_sim) else np.asarray(alpha_sim)[acc]
    wd = iw[acc] * d[acc]
    L = np.zeros((m, n_bins))
    for j in range(m):
        L[j] = np.bincount(fbin[acc, j], weights=wd * a[:, j], minlength=n_bins)
    if settings.likelihood == "mean":
        for j in range(m):
            n = np.bincount(fbin[:, j], weights=iw, minlength=n_bins)
            L[j] = np.where(n > 0, L[j] / np.where(n > 0, n, 1.0), 0.0)
    act = (wd[:, None] * a).sum(axis=0) / max(wd.sum(), 1e-300)
    informative = (act >= settings.alpha_min) & (L.sum(axis=1) > 0)
    return L, informative, {"threshold": thr, "n_accepted": int(len(acc)), "mean_activation": act}


def log_factor(L: np.ndarray, informative: np.ndarray, floor: float) -> np.ndarray:
    """``log(L / max L + floor)`` per muscle; 0 for muscles the test does not inform."""
    mx = L.max(axis=-1, keepdims=True)
    out = np.log(np.where(mx > 0, L / np.where(mx > 0, mx, 1.0), 1.0) + floor)
    return np.where(np.asarray(informative)[..., None], out, 0.0)


def posterior_from_loglik(log_prior: np.ndarray, log_lik: np.ndarray) -> np.ndarray:
    """Eq. 6.1 on the grid: ``p ∝ p_0 prod_t L_t`` from summed log factors (..., m, n_bins)."""
    z = log_prior + log_lik
    z = z - z.max(axis=-1, keepdims=True)
    p = np.exp(z)
    return p / p.sum(axis=-1, keepdims=True)


def pdf_moments(pdf: np.ndarray, grid: StrengthGrid) -> tuple[np.ndarray, np.ndarray]:
    """Expected value (the point estimate f_c) and variance of each muscle's PDF (..., m)."""
    c = grid.centres
    mean = (pdf * c).sum(axis=-1)
    var = (pdf * (c - mean[..., None]) ** 2).sum(axis=-1)
    return mean, var


def pdf_entropy(pdf: np.ndarray, grid: StrengthGrid) -> np.ndarray:
    """Eq. 6.3 per muscle as a differential entropy (nats): ``-sum p log p + log h`` (..., m)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -np.where(pdf > 0, pdf * np.log(pdf), 0.0).sum(axis=-1)
    return h + np.log(grid.widths)


def _mean_field_weights(sim: SimulatedSet, pdf: np.ndarray) -> np.ndarray:
    """Candidate weights ``iw prod_j p_j(b_kj) / p0_j(b_kj)`` (the posterior if the muscles were independent)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(sim.prior_pdf > 0, pdf / sim.prior_pdf, 0.0)
    logw = np.zeros(sim.N)
    for j in range(sim.m):
        logw += np.log(np.maximum(ratio[j][sim.fbin[:, j]], 1e-300))
    logw -= logw.max()
    return sim.iw * np.exp(logw)


def _draw_measurements(sim: SimulatedSet, i: int, n: int, rng: np.random.Generator,
                       weights: np.ndarray | None) -> np.ndarray:
    """``N_S`` simulated wrenches ``w^s ~ {w_sim}_i`` (producible candidates only)."""
    w = sim.w[:, i]
    if weights is None and sim.uniform_weights:     # uniform over the producible candidates (rejection)
        idx = rng.integers(sim.N, size=n)
        for _ in range(100):
            bad = w[idx] <= 0
            if not bad.any():
                return w[idx]
            idx[bad] = rng.integers(sim.N, size=int(bad.sum()))
    p = np.cumsum((sim.iw if weights is None else weights) * (w > 0))
    if p[-1] <= 0:
        return np.zeros(0)
    return w[np.minimum(np.searchsorted(p, rng.random(n) * p[-1], side="right"), sim.N - 1)]


def _fast_likelihoods(sim: SimulatedSet, i: int, w_s: np.ndarray, settings: SequentialSettings):
    """Forward-simulated Algorithm 8 for many ``w^s`` at once from the binned tables: L (S, m, nb), informative."""
    edges = sim.wedges[i]
    centre = np.r_[0.0, np.sqrt(edges[1:] * edges[:-1])]             # bin 0 = zero wrench
    r = np.abs(centre[None, :] - w_s[:, None]) / w_s[:, None]        # (S, V)
    d = np.exp(-(settings.epsilon * r) ** 2)
    cnt = sim.wcount[i]
    keep = (1.0 - settings.q / 100.0) * cnt.sum()
    # rejection (Algorithm 8 step 2) on the binned counts: the bins nearest to w^s hold the accepted share,
    # the last one partly
    order = np.argsort(r, axis=1, kind="stable")
    c_o = cnt[order]
    frac_sorted = np.clip((keep - (np.cumsum(c_o, axis=1) - c_o)) / np.where(c_o > 0, c_o, 1.0), 0.0, 1.0)
    frac = np.empty_like(frac_sorted)
    frac[np.arange(len(w_s))[:, None], order] = frac_sorted
    g = frac * d                                                     # (S, V)
    V, m, nb = sim.A.shape[1:]
    # Only the accepted wrench bins of each w^s (a window of ~10-400 of the n_wbins) contribute: a sparse
    # (S, V) x dense (V, m nb) product.
    from scipy.sparse import csr_matrix

    L = np.asarray(csr_matrix(g.astype(np.float32)) @ sim.A[i].reshape(V, m * nb))
    L = L.reshape(len(w_s), m, nb).astype(float)
    if settings.likelihood == "mean":
        n = sim.prior_pdf * sim.iw.sum()
        L = np.where(n > 0, L / np.where(n > 0, n, 1.0), 0.0)
    act = (g @ sim.activation_sums[i]) / np.maximum(g @ cnt, 1e-300)[:, None]   # (S, m)
    informative = (act >= settings.alpha_min) & (L.sum(axis=2) > 0)
    return L, informative


def expected_entropy_reduction(sim: SimulatedSet, log_lik: np.ndarray, remaining: Sequence[int],
                               settings: SequentialSettings, rng: np.random.Generator, exact: bool = False,
                               n_sim: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 6.6: ``Delta S_{i,j} = S_c,j - mean_s S^s_{sim,i,j}`` for every remaining direction i.

    ``log_lik`` (m, nb): summed log factors of the tests so far (the current posterior). ``exact=True`` runs
    Algorithm 8 on every candidate for every simulated measurement (needs ``sim.alpha``); the default uses
    the binned tables (module docstring). Returns ``dS`` (len(remaining), m) and the current entropy (m,).
    """
    n_sim = n_sim or settings.n_sim
    log_prior = np.log(np.maximum(sim.prior_pdf, 1e-300))
    post = posterior_from_loglik(log_prior, log_lik)
    S_c = pdf_entropy(post, sim.grid)
    weights = _mean_field_weights(sim, post) if settings.predictive == "posterior" else None
    dS = np.zeros((len(remaining), sim.m))
    for r_i, i in enumerate(remaining):
        w_s = _draw_measurements(sim, i, n_sim, rng, weights)
        if len(w_s) == 0:
            continue
        if exact:
            if sim.alpha is None:
                raise ValueError("exact expected entropy reduction needs SimulatedSet.alpha (keep_alpha=True)")
            Ls, inf = zip(*[data_likelihood(sim.w[:, i], sim.alpha[:, i, :], ws, sim.fbin, sim.iw, sim.grid.n_bins,
                                            settings)[:2] for ws in w_s])
            Ls, inf = np.stack(Ls), np.stack(inf)
        else:
            Ls, inf = _fast_likelihoods(sim, i, w_s, settings)
        lf = log_factor(Ls, inf, settings.likelihood_floor)
        S_s = pdf_entropy(posterior_from_loglik(log_prior, log_lik[None] + lf), sim.grid)
        dS[r_i] = S_c - S_s.mean(axis=0)
    return dS, S_c


def select_direction(dS: np.ndarray, gamma: np.ndarray | None = None) -> int:
    """Eq. 6.7 ``argmax_i sum_j dS_ij / m``, or Eq. 6.8 with muscle priorities ``gamma`` (row of ``dS``)."""
    g = np.ones(dS.shape[1]) if gamma is None else np.asarray(gamma, float)
    return int(np.argmax((dS * g[None, :]).sum(axis=1) / dS.shape[1]))


def activation_bounds(activations, muscle_names: Sequence[str], band: float):
    """``activations``: None, a pair (lb, ub) of (m,) arrays, or {muscle: measured activation} (+- band)."""
    if activations is None:
        return None
    m = len(muscle_names)
    if isinstance(activations, Mapping):
        lb, ub = np.zeros(m), np.ones(m)
        for name, a in activations.items():
            if name not in muscle_names:
                raise ValueError(f"unknown muscle {name!r}; known: {list(muscle_names)}")
            j = list(muscle_names).index(name)
            lb[j], ub[j] = max(0.0, a - band), min(1.0, a + band)
        return lb, ub
    lb, ub = (np.asarray(x, float) for x in activations)
    if lb.shape != (m,) or ub.shape != (m,):
        raise ValueError(f"activation bounds must have {m} entries")
    return lb, ub


@dataclass
class Proposal:
    """Output of :meth:`SequentialState.propose`: Eq. 6.6 per remaining direction and muscle, and the choice."""

    directions: list[str]
    muscles: list[str]
    dS: np.ndarray            # (len(directions), m)
    S_current: np.ndarray     # (m,)
    choice: str
    gamma: np.ndarray | None = None

    def table(self) -> pd.DataFrame:
        df = pd.DataFrame(self.dS, columns=self.muscles)
        df.insert(0, "direction", self.directions)
        g = np.ones(len(self.muscles)) if self.gamma is None else self.gamma
        df["score"] = (self.dS * g).sum(axis=1) / len(self.muscles)
        df["selected"] = df["direction"] == self.choice
        return df


@dataclass
class _Step:
    direction: str
    force: float
    w_meas: float
    bounds: tuple | None
    loglik: np.ndarray        # (m, nb)
    informative: np.ndarray   # (m,)
    info: dict


class SequentialState:
    """Algorithm 7, one measurement at a time (pipeline and clinician-in-the-loop).

    ``propose(gamma)`` -> :class:`Proposal` (Eq. 6.6 per remaining direction and muscle; Eq. 6.7/6.8 choice);
    ``update(direction, force, activations=None)`` runs Algorithm 8 on the measured force (N) and updates
    the posterior; ``undo()`` removes the last measurement; ``estimate()`` is the current E / Var / entropy;
    ``save``/``load`` keep the measurement history (the candidate set is saved separately by
    :meth:`SimulatedSet.save` and checked by its key). Random draws (Algorithm 9) use the caller's Generator.
    """

    def __init__(self, model: ReducedModel, sim: SimulatedSet, force_scale: np.ndarray,
                 settings: SequentialSettings, seed: int | None = None, alpha_cache: dict | None = None):
        self.model = model
        self.sim = sim
        self.force_scale = np.asarray(force_scale, float)
        self.settings = settings
        self.seed = seed
        self.steps: list[_Step] = []
        # wrenches / activations of accepted candidates per direction and activation bounds; may be shared
        # between states on the same candidates (e.g. the same set on several strength grids)
        self.alpha_cache = {} if alpha_cache is None else alpha_cache
        self.log_prior = np.log(np.maximum(sim.prior_pdf, 1e-300))

    # -- state
    @property
    def tested(self) -> list[str]:
        return [s.direction for s in self.steps]

    @property
    def remaining(self) -> list[str]:
        return [d for d in self.sim.directions if d not in self.tested]

    @property
    def log_lik(self) -> np.ndarray:
        out = np.zeros_like(self.log_prior)
        for s in self.steps:
            out = out + s.loglik
        return out

    def posterior(self) -> np.ndarray:
        return posterior_from_loglik(self.log_prior, self.log_lik)

    def estimate(self) -> pd.DataFrame:
        p = self.posterior()
        E, V = pdf_moments(p, self.sim.grid)
        return pd.DataFrame({"muscle": list(self.model.muscle_names), "f_c": E, "v_c": V, "sd_c": np.sqrt(V),
                             "entropy": pdf_entropy(p, self.sim.grid)})

    # -- Algorithm 9
    def propose(self, rng: np.random.Generator, gamma: np.ndarray | Mapping[str, float] | None = None,
                exact: bool = False) -> Proposal:
        rem = self.remaining
        if not rem:
            raise ValueError("every direction has been tested (each direction is tested once)")
        if isinstance(gamma, Mapping):
            gamma = np.array([float(gamma.get(n, 0.0)) for n in self.model.muscle_names])
        idx = [self.sim.directions.index(d) for d in rem]
        dS, S_c = expected_entropy_reduction(self.sim, self.log_lik, idx, self.settings, rng, exact=exact)
        return Proposal(rem, list(self.model.muscle_names), dS, S_c, rem[select_direction(dS, gamma)],
                        None if gamma is None else np.asarray(gamma, float))

    # -- Algorithm 7 steps (2)-(9)
    def likelihood(self, direction: str, force: float, activations=None) -> _Step:
        """Algorithm 8 for a measured ``force`` (N) in ``direction``; with activation bounds the candidates
        are simulated again in that direction (Algorithm 7 step 3), else the general data set is used."""
        i = self.sim.directions.index(direction)
        w_meas = float(force) * float(self.force_scale[i])
        if not np.isfinite(w_meas) or w_meas <= 0:
            raise ValueError(f"measured force must be positive, got {force!r}")
        bounds = activation_bounds(activations, self.model.muscle_names, self.settings.emg_band)
        u = self.sim.U[i:i + 1]
        lb, ub = (None, None) if bounds is None else (bounds[0][None], bounds[1][None])
        key = (direction, None if bounds is None else np.asarray(bounds, float).tobytes())
        hit = self.alpha_cache.setdefault(key, {})
        if bounds is None:
            w_sim = self.sim.w[:, i]
        else:  # Algorithm 7 step 3: wrenches of every candidate within the measured activation bounds
            if "w" not in hit:
                w_b, _, st = solve(self.model, self.sim.F, u, lb, ub, return_alpha=False)
                hit["w"] = np.where(st[:, 0] == _OPT, w_b[:, 0], 0.0)
            w_sim = hit["w"]
        if bounds is None and self.sim.alpha is not None:
            alpha = self.sim.alpha[:, i, :]
        else:
            def alpha(idx):  # activations of the accepted candidates only (cached per direction and bounds)
                if "idx" in hit and np.array_equal(hit["idx"], idx):
                    return hit["alpha"]
                _, a, st = solve(self.model, self.sim.F[idx], u, lb, ub, return_alpha=True)
                hit["idx"], hit["alpha"] = idx, np.where((st[:, 0] == _OPT)[:, None], np.nan_to_num(a[:, 0, :]), 0.0)
                return hit["alpha"]
        L, inf, info = data_likelihood(w_sim, alpha, w_meas, self.sim.fbin, self.sim.iw, self.sim.grid.n_bins,
                                       self.settings)
        info["n_not_producible"] = int((w_sim <= 0).sum())
        return _Step(direction, float(force), w_meas, None if bounds is None else tuple(map(list, bounds)),
                     log_factor(L, inf, self.settings.likelihood_floor), inf, info)

    def update(self, direction: str, force: float, activations=None) -> pd.DataFrame:
        if direction not in self.sim.directions:
            raise ValueError(f"unknown direction {direction!r}; known: {self.sim.directions}")
        if direction in self.tested:
            raise ValueError(f"direction {direction!r} has already been tested (each direction is tested once)")
        self.steps.append(self.likelihood(direction, force, activations))
        return self.estimate()

    def undo(self) -> str:
        if not self.steps:
            raise ValueError("nothing to undo")
        return self.steps.pop().direction

    # -- persistence (history only; the candidate set is saved with SimulatedSet.save)
    def to_dict(self) -> dict:
        return {"model": self.model.name, "seed": self.seed, "settings": asdict(self.settings),
                "sim_key": sim_key(self.sim),
                "steps": [{"direction": s.direction, "force": s.force, "bounds": s.bounds} for s in self.steps]}

    def save(self, path: str | Path) -> None:
        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(self.to_dict(), indent=2))
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path, model: ReducedModel, sim: SimulatedSet, force_scale: np.ndarray) -> "SequentialState":
        d = json.loads(Path(path).read_text())
        if d["sim_key"] != sim_key(sim):
            raise ValueError(f"{path}: saved for another candidate set (key {d['sim_key']}, have {sim_key(sim)})")
        st = cls(model, sim, force_scale, SequentialSettings(**d["settings"]), d.get("seed"))
        for s in d["steps"]:
            st.update(s["direction"], s["force"], None if s["bounds"] is None else tuple(map(np.asarray, s["bounds"])))
        return st


def sim_key(sim: SimulatedSet) -> str:
    h = hashlib.sha256()
    for a in (sim.F, sim.U, sim.grid.edges, sim.iw):
        h.update(np.ascontiguousarray(a, float).tobytes())
    return h.hexdigest()[:16]


def run_sequence(state: SequentialState, measure: Callable[[str], tuple[float, object]], rng: np.random.Generator,
                 gamma=None, order: Sequence[str] | None = None, n_max: int | None = None,
                 progress: Callable[[str], None] | None = None) -> tuple[list[Proposal], pd.DataFrame]:
    """Algorithm 7: propose (unless ``order`` is fixed), measure, update, until every direction is tested.

    ``measure(direction) -> (force_N, activations)``. Returns the proposals (one per iteration; None entries
    for a fixed order) and a long table of E / Var / entropy per iteration (0 = prior) and muscle.
    """
    rows = []

    def record(it, direction):
        est = state.estimate()
        est.insert(0, "iteration", it)
        est.insert(1, "direction", direction)
        rows.append(est)

    record(0, "")
    proposals = []
    n_max = n_max or state.sim.K
    while state.remaining and len(state.steps) < n_max:
        if order is None:
            prop = state.propose(rng, gamma)
            d = prop.choice
        else:
            prop, d = None, order[len(state.steps)]
        proposals.append(prop)
        force, act = measure(d)
        state.update(d, force, act)
        record(len(state.steps), d)
        if progress:
            e = rows[-1]
            progress(f"iteration {len(state.steps)}: {d}; mean entropy {e['entropy'].mean():.3f}")
    return proposals, pd.concat(rows, ignore_index=True)


def stop_by_expected_gain(dS_best: Sequence[float], frac: float = 0.1) -> int:
    """Prospective stop: the number of measurements after which the best remaining expected entropy
    reduction (Eq. 6.7 score) falls below ``frac`` of the first iteration's (``dS_best[t]`` = score of the
    proposal at iteration t + 1)."""
    dS_best = np.asarray(dS_best, float)
    for t in range(1, len(dS_best)):
        if dS_best[t] < frac * dS_best[0]:
            return t
    return len(dS_best)


def joint_ess(sim: SimulatedSet, pdf: np.ndarray) -> float:
    """Effective sample size share of the mean-field posterior weights of the candidates (1 = prior)."""
    w = _mean_field_weights(sim, pdf)
    return float(w.sum() ** 2 / max((w ** 2).sum(), 1e-300) / sim.N)


def fit_point_estimate(model: ReducedModel, data: Dataset, f_c: np.ndarray, epsilon: float) -> tuple[float, pd.DataFrame]:
    """``D(f_c)`` (Eqs. 5.5/5.6, as in Table 6.1) and the per-direction fit of the point estimate."""
    w, _, st = solve(model, np.asarray(f_c, float)[None], data.U, data.alpha_lb, data.alpha_ub)
    d = data_discrepancy(w[0], data.w_meas, epsilon)
    fit = pd.DataFrame({"direction": data.directions, "measured_N": data.forces, "simulated_N": w[0] / data.force_scale,
                        "d": d, "status": [STATUS_CODES[int(x)] for x in st[0]]})
    return float(composite_score(d)), fit
