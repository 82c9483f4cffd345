"""The largest force inside the Appendix A direction-matching window, with a certified bracket.

A test's window (Appendix A, Eq. A.2) around its target unit wrench ``u = (M0, F0)`` (the model's task space:
spatial ``(Mx, My, Mz, Fx, Fy, Fz)``, planar ``(Mz, Fx, Fy)``) holds the wrenches ``w = (M, F)`` whose moment and
force unit vectors are within an angle ``theta`` of ``M0 / |M0|`` and ``F0 / |F0|`` and whose ratio
``R_fm = |F| / (|M| + |F|)`` is within ``rfm (1 -+ q)`` of the target's ``rfm`` (planar: the moment is a
scalar, its "unit vector" is its sign). A wrench is producible iff ``R diag(f) alpha = J^T w`` for some
``alpha_lb <= alpha <= alpha_ub`` (the max-wrench LP, Eq. 4.1 / 5.2). The predicted force of the test is

    F_win = c * max { |F| : w producible, w in the window },      c = force per unit |F| of the target

(``c = 1`` when the direction table's force scale is that of the target's force part).

The window is a cone, but not a convex one: the ratio constraint compares two norms, and the objective
maximises a norm. The maximum is found by branch and bound over the directions of ``F`` and ``M`` in gnomonic
coordinates (a unit vector within ``theta`` of the axis ``a`` is ``(a + x1 e1 + x2 e2) / norm`` with
``|x| <= tan(theta)``). A region of directions (:class:`_Part`: the cap's circumscribed octagon, polar sectors of
it, an interval for a planar force) is a polyhedral cone, and every ``v`` in it has ``v . c <= |v| <= k (v . c)``
for its centre direction ``c`` and ``k`` = 1 / cos of its largest angle to ``c``. Replacing ``|F|`` and ``|M|`` by
these bounds, in the direction that enlarges the set, gives an LP whose optimum is an **upper bound** on the maximum
over the region. Fixing the directions of the upper-bound LP's solution (projected into the window) gives an LP with
the exact constraints whose optimum is a producible window wrench: a **lower bound** (a solution that lies in the
window already is one as it is). Regions are split (the part whose bound is the looser at the LP's solution) until
the largest open upper bound is within ``tol`` of the best lower bound. The result is the bracket ``[lower, upper]``
with ``upper <= lower (1 + tol)`` (or, where ``max_nodes`` stops it first, the bracket reached, flagged), and the
wrench of the lower bound (its direction reproduces the lower bound as a plain max-wrench LP). At ``theta = 0`` and
``q = 0`` the window is the target ray and the answer is the plain max-wrench force (one LP).

A pure-force target (``M0 = 0``) keeps ``M = 0`` (the moment's direction is undefined), as the 10-point
approximation does; a pure-moment target has no force (0). A window in which no wrench is producible (activation
floors) or whose root LP is unbounded (it holds a direction the joints do not resist) gives no force (0), as the
plain LP's 'zero' and 'unbounded' do.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import highspy
import numpy as np

from neckstrength.wrench.problem import set_colwise_matrix

_EPS = 1e-12
_SIDES = 8          # the circumscribed polygon of a whole cap (before it is split into sectors)
_TANGENTS = 5       # tangents of a sector's outer arc


@dataclass(frozen=True)
class WindowSpec:
    """One test's window in the model's task space (``dm`` moment components, then the force components)."""

    u: np.ndarray            # target unit wrench (task space)
    dm: int                  # number of moment components (3 spatial, 1 planar)
    theta: float             # angle (rad)
    r_lo: float              # R_fm bounds
    r_hi: float
    c: float                 # force (N) per unit |F|

    @staticmethod
    def make(u: np.ndarray, dm: int, angle_deg: float, ratio_rel: float, share: float,
             force_per_unit_wrench: float) -> "WindowSpec":
        u = np.asarray(u, float)
        m0, f0 = np.linalg.norm(u[:dm]), np.linalg.norm(u[dm:])
        rfm = f0 / (m0 + f0) if (m0 + f0) > 0 else 0.0
        q = float(ratio_rel) * float(share)
        c = float(force_per_unit_wrench) / f0 if f0 > _EPS else 0.0
        return WindowSpec(u, dm, np.radians(float(angle_deg) * float(share)), rfm * (1 - q),
                          min(1.0, rfm * (1 + q)), c)

    @property
    def pure_force(self) -> bool:
        return np.linalg.norm(self.u[:self.dm]) <= _EPS

    @property
    def pure_moment(self) -> bool:
        return np.linalg.norm(self.u[self.dm:]) <= _EPS


@dataclass
class WindowResult:
    force: float             # lower bound: the force of a producible window wrench (N)
    upper: float             # certified upper bound (N)
    wrench: np.ndarray       # that wrench (task space), zero when none
    nodes: int               # LPs of upper bounds solved
    converged: bool          # upper <= force * (1 + tol)


def _basis(a: np.ndarray, hint: np.ndarray | None = None) -> np.ndarray:
    """Orthonormal vectors spanning the complement of unit vector ``a`` (rows)."""
    d = len(a)
    if d == 1:
        return np.zeros((0, 1))
    if d == 2:
        return np.array([[-a[1], a[0]]])
    h = np.array([1.0, 0.0, 0.0]) if hint is None else np.asarray(hint, float)
    e = h - np.dot(h, a) * a
    if np.linalg.norm(e) < 1e-9:
        h = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e = h - np.dot(h, a) * a
    e /= np.linalg.norm(e)
    return np.array([e, np.cross(a, e)])


class _Part:
    """The force or moment part of the wrench: its components in ``w``, axis ``a``, tangent basis ``E`` and the
    regions of its directions that the branch and bound splits.

    Gnomonic coordinates ``x`` (``g`` of them: 2 for a 3-D part, 1 for a 2-D part, 0 for a scalar moment, whose
    direction is its sign): the direction ``(a + x E) / norm``, in the window iff ``|x| <= t = tan(theta)``.
    Regions: ``g = 1``: an interval ``(lo, hi)`` of ``x``; ``g = 2``: the whole disk (its circumscribed octagon,
    split into four quadrants) or a polar sector ``(r1, r2, p1, p2)`` of it (radius, angle; span <= pi), described
    by linear rows in ``w`` (the rays at ``p1``, ``p2``, five tangents of the arc ``|x| = r2`` and the chord
    ``x . m >= r1 cos(h)`` through the inner corners, ``m`` the middle direction, ``h`` half the span): a polyhedral
    cone that contains the sector's directions."""

    def __init__(self, sl: slice, axis: np.ndarray, t: float, hint=None):
        self.sl, self.a, self.t = sl, axis, t
        self.E = _basis(axis, hint)
        self.g = self.E.shape[0]

    def roots(self) -> list[tuple]:
        t = self.t
        if self.g == 0:
            return [()]
        if self.g == 1:
            return [(-t, t)]
        if t <= 0:
            return [(0.0, 0.0, 0.0, 0.0)]
        return [("full",)]

    def _vec(self, d: int, y: np.ndarray) -> np.ndarray:
        """The row of ``w`` whose product is ``F . (y E)`` (``y`` in the tangent plane)."""
        v = np.zeros(d)
        v[self.sl] = y @ self.E
        return v

    def corners(self, reg: tuple) -> np.ndarray:
        """Gnomonic coordinates of the extreme rays of the region's cone."""
        if self.g == 0:
            return np.zeros((1, 0))
        if self.g == 1:
            return np.array([[reg[0]], [reg[1]]])
        if reg[0] == "full":
            R = self.t / np.cos(np.pi / _SIDES)
            return np.array([[R * np.cos(p), R * np.sin(p)] for p in (np.arange(_SIDES) + 0.5) * 2 * np.pi / _SIDES])
        r1, r2, p1, p2 = reg
        tau = np.linspace(p1, p2, _TANGENTS)
        mid = 0.5 * (tau[1:] + tau[:-1])
        R2 = r2 / np.cos(0.5 * (tau[1] - tau[0]))
        pts = [(r1, p1), (r1, p2), (r2, p1), (r2, p2)] + [(R2, p) for p in mid]
        return np.array([[r * np.cos(p), r * np.sin(p)] for r, p in pts])

    def rows(self, d: int, reg: tuple) -> list[np.ndarray]:
        """Rows ``r . w <= 0`` of the region's cone."""
        a = np.zeros(d)
        a[self.sl] = self.a
        out = [-a]                                       # part . a >= 0
        if self.g == 1:
            e = self._vec(d, np.array([1.0]))
            out += [e - reg[1] * a, reg[0] * a - e]
        elif self.g == 2 and reg[0] == "full":
            for p in np.arange(_SIDES) * 2 * np.pi / _SIDES:
                out.append(self._vec(d, np.array([np.cos(p), np.sin(p)])) - self.t * a)
        elif self.g == 2:
            r1, r2, p1, p2 = reg
            if r2 <= 0:
                return self.fixed_rows(d, np.zeros(2))
            h = 0.5 * (p2 - p1)
            pm = 0.5 * (p1 + p2)
            m = self._vec(d, np.array([np.cos(pm), np.sin(pm)]))
            out.append(self._vec(d, np.array([np.sin(p1), -np.cos(p1)])))     # angle >= p1
            out.append(self._vec(d, np.array([-np.sin(p2), np.cos(p2)])))     # angle <= p2
            for p in np.linspace(p1, p2, _TANGENTS):                          # tangents of the arc |x| = r2
                out.append(self._vec(d, np.array([np.cos(p), np.sin(p)])) - r2 * a)
            if r1 > 0:
                out.append(r1 * np.cos(h) * a - m)
        return out

    def fixed_rows(self, d: int, x: np.ndarray) -> list[np.ndarray]:
        """Rows that fix the part's direction to gnomonic coordinates ``x``."""
        a = np.zeros(d)
        a[self.sl] = self.a
        out = [-a]
        for i in range(self.g):
            e = np.zeros(d)
            e[self.sl] = self.E[i]
            out += [e - x[i] * a, x[i] * a - e]
        return out

    def direction(self, x: np.ndarray) -> np.ndarray:
        v = self.a + x @ self.E
        return v / np.linalg.norm(v)

    def centre(self, reg: tuple) -> tuple[np.ndarray, float]:
        """A unit direction ``c`` and ``k = 1 / cos`` of the largest angle between ``c`` and the region's cone:
        every ``v`` in it has ``v . c <= |v| <= k (v . c)``."""
        X = self.corners(reg)
        c = self.direction(X.mean(axis=0))
        if self.g == 0:
            return c, 1.0
        cos = min(float(np.dot(self.direction(x), c)) for x in X)
        return c, 1.0 / max(cos, 1e-12)

    def size(self, reg: tuple) -> float:
        """Largest extent of the region (gnomonic units)."""
        if self.g == 0:
            return 0.0
        if self.g == 1:
            return reg[1] - reg[0]
        if reg[0] == "full":
            return 2 * self.t
        r1, r2, p1, p2 = reg
        return max(r2 - r1, r2 * (p2 - p1))

    def split(self, reg: tuple) -> list[tuple]:
        if self.g == 1:
            mid = 0.5 * (reg[0] + reg[1])
            return [(reg[0], mid), (mid, reg[1])]
        if reg[0] == "full":
            q = np.pi / 2
            return [(0.0, self.t, i * q, (i + 1) * q) for i in range(4)]
        r1, r2, p1, p2 = reg
        if r2 - r1 >= r2 * (p2 - p1):
            mid = 0.5 * (r1 + r2)
            return [(r1, mid, p1, p2), (mid, r2, p1, p2)]
        mid = 0.5 * (p1 + p2)
        return [(r1, r2, p1, mid), (r1, r2, mid, p2)]

    def coords(self, v: np.ndarray) -> np.ndarray:
        """Gnomonic coordinates of the part ``v`` of a wrench, projected into the disk."""
        p = float(np.dot(v, self.a))
        if self.g == 0:
            return np.zeros(0)
        if p <= _EPS:
            return np.zeros(self.g)
        x = self.E @ v / p
        n = np.linalg.norm(x)
        return x * (self.t / n) if n > self.t else x

    def excess(self, v: np.ndarray) -> float:
        """How far the direction of ``v`` lies outside the window (gnomonic radius over ``t``; 0 inside)."""
        if self.g == 0:
            return 0.0
        p = float(np.dot(v, self.a))
        return max(0.0, float(np.linalg.norm(self.E @ v)) / max(p, _EPS) - self.t)


class WindowSolver:
    """Branch and bound for one strength vector and test: see the module docstring.

    ``R`` (n x m') moment arms, ``JT`` (n x d), column strengths ``fa`` (m'), bounds ``lb``/``ub`` (m')."""

    def __init__(self, R: np.ndarray, JT: np.ndarray, fa: np.ndarray, lb: np.ndarray, ub: np.ndarray):
        self.n, self.m = R.shape
        self.d = JT.shape[1]
        A = np.hstack([R, -JT])
        self.h = highspy.Highs()
        self.h.setOptionValue("output_flag", False)
        self.h.setOptionValue("log_to_console", False)
        lp = highspy.HighsLp()
        nc = self.m + self.d
        lp.num_col_ = nc
        lp.num_row_ = self.n
        lp.col_cost_ = np.zeros(nc)
        inf = highspy.kHighsInf
        lp.col_lower_ = np.r_[lb * fa, np.full(self.d, -inf)]
        lp.col_upper_ = np.r_[ub * fa, np.full(self.d, inf)]
        lp.row_lower_ = np.zeros(self.n)
        lp.row_upper_ = np.zeros(self.n)
        lp.sense_ = highspy.ObjSense.kMaximize
        set_colwise_matrix(lp, A)
        self.h.passModel(lp)
        self.wcols = np.arange(self.m, nc, dtype=np.int32)
        self.fa = np.asarray(fa, float)
        self.n_lp = 0

    def set_bounds(self, lb: np.ndarray, ub: np.ndarray) -> None:
        """Other activation bounds (another test's), the same strengths."""
        self.h.changeColsBounds(self.m, np.arange(self.m, dtype=np.int32), lb * self.fa, ub * self.fa)

    def _lp(self, cost: np.ndarray, rows: list[np.ndarray]) -> np.ndarray | None:
        """Maximise ``cost . w`` with the extra rows ``r . w <= 0``; the optimal ``w`` or None (infeasible)."""
        h = self.h
        extra = h.getNumRow() - self.n
        if extra:
            h.deleteRows(extra, np.arange(self.n, self.n + extra, dtype=np.int32))
        if rows:
            Rw = np.array(rows)
            k = len(rows)
            idx, val, st = [], [], []
            for r in Rw:
                st.append(len(idx))
                nz = np.nonzero(np.abs(r) > 1e-15)[0]
                idx.extend((self.m + nz).tolist())
                val.extend(r[nz].tolist())
            h.addRows(k, np.full(k, -highspy.kHighsInf), np.zeros(k), len(idx), np.array(st, dtype=np.int32),
                      np.array(idx, dtype=np.int32), np.array(val, dtype=float))
        h.changeColsCost(self.d, self.wcols, np.asarray(cost, float))
        h.run()
        self.n_lp += 1
        st = h.getModelStatus()
        if st not in (highspy.HighsModelStatus.kOptimal, highspy.HighsModelStatus.kInfeasible):
            # a warm start that HiGHS could not use (status 'Not Set' seen after rows were exchanged): from scratch
            h.clearSolver()
            h.run()
            self.n_lp += 1
            st = h.getModelStatus()
        if st != highspy.HighsModelStatus.kOptimal:
            return None
        return np.asarray(h.getSolution().col_value)[self.m:]

    def solve(self, spec: WindowSpec, tol: float = 0.005, max_nodes: int = 400) -> WindowResult:
        d, dm = self.d, spec.dm
        zero = WindowResult(0.0, 0.0, np.zeros(d), 0, True)
        if spec.pure_moment or spec.c <= 0:
            return zero
        u = spec.u
        t = float(np.tan(spec.theta))
        Fp = _Part(slice(dm, d), u[dm:] / np.linalg.norm(u[dm:]), t, hint=u[:dm] if dm == 3 else None)
        pure_force = spec.pure_force
        Mp = None if pure_force else _Part(slice(0, dm), u[:dm] / np.linalg.norm(u[:dm]), t,
                                           hint=u[dm:] if dm == 3 else None)
        a_lo = spec.r_lo / (1 - spec.r_lo) if spec.r_lo < 1 else np.inf
        a_hi = spec.r_hi / (1 - spec.r_hi) if spec.r_hi < 1 else np.inf
        ma_vec = np.zeros(d)
        fixed_rows = []
        if pure_force:
            for i in range(dm):
                e = np.zeros(d)
                e[i] = 1.0
                fixed_rows += [e, -e]
        else:
            ma_vec[Mp.sl] = Mp.a

        def bound(rowsF, cF, kF, rowsM, cM, kM):
            """max k_F (F . c_F) over the cones, with the ratio rows from the norm bounds: (value, w) or None."""
            cf = np.zeros(d)
            cf[Fp.sl] = cF
            rows = list(fixed_rows) + rowsF
            if Mp is not None:
                cm = np.zeros(d)
                cm[Mp.sl] = cM
                rows += rowsM
                # on the cones: F . cF <= |F| <= kF (F . cF), M . cM <= |M| <= kM (M . cM)
                if a_lo > 0:
                    rows.append(a_lo * cm - kF * cf if np.isfinite(a_lo) else ma_vec)
                if np.isfinite(a_hi):
                    rows.append(cf - a_hi * kM * cm)
            w = self._lp(kF * cf, rows)
            if w is None:
                return None
            return kF * float(np.dot(cf, w)), w

        def node(rF, rM):
            cF, kF = Fp.centre(rF)
            cM, kM = Mp.centre(rM) if Mp is not None else (None, 1.0)
            return bound(Fp.rows(d, rF), cF, kF, Mp.rows(d, rM) if Mp is not None else [], cM, kM)

        def inside(w) -> bool:
            """Whether ``w`` lies in the window (then it is a producible window wrench as it is)."""
            Fv = w[Fp.sl]
            nF = float(np.linalg.norm(Fv))
            if np.dot(Fp.a, Fv) <= _EPS or Fp.excess(Fv) > t * 1e-9:
                return False
            if Mp is None:
                return True
            Mv = w[Mp.sl]
            nM = float(np.linalg.norm(Mv))
            if nM <= 1e-9 * max(nF, 1.0):                 # no moment: its direction does not matter
                return nF <= a_hi * nM * (1 + 1e-9) or not np.isfinite(a_hi)
            if np.dot(Mp.a, Mv) < -1e-12 or Mp.excess(Mv) > t * 1e-9:
                return False
            return a_lo * nM <= nF * (1 + 1e-9) and nF <= a_hi * nM * (1 + 1e-9)

        def lower(w):
            """A producible window wrench with the directions of ``w`` (projected into the window)."""
            if inside(w):
                return float(np.linalg.norm(w[Fp.sl])), w
            x = Fp.coords(w[Fp.sl])
            got = None
            if Mp is None:
                got = bound(Fp.fixed_rows(d, x), Fp.direction(x), 1.0, [], None, 1.0)
            else:
                y = Mp.coords(w[Mp.sl])
                got = bound(Fp.fixed_rows(d, x), Fp.direction(x), 1.0, Mp.fixed_rows(d, y), Mp.direction(y), 1.0)
            if got is None:
                return 0.0, np.zeros(d)
            return float(np.linalg.norm(got[1][Fp.sl])), got[1]

        heap = []
        best, best_w = 0.0, np.zeros(d)
        nodes = 0
        counter = 0
        pruned_ub = 0.0
        exact_tol = 1e-9
        for rF in Fp.roots():
            for rM in (Mp.roots() if Mp is not None else [()]):
                got = node(rF, rM)
                nodes += 1
                if got is None:
                    continue
                lb_k, wl = lower(got[1])
                if lb_k > best:
                    best, best_w = lb_k, wl
                counter += 1
                heapq.heappush(heap, (-got[0], counter, (rF, rM), got[1]))
        if not heap:
            return zero
        while heap:
            ub, _, (rF, rM), w = heap[0]
            ub = -ub
            if ub <= best * (1 + tol) + 1e-12 or nodes >= max_nodes:
                break
            heapq.heappop(heap)
            # split the part whose relaxation is the looser at this node's solution: the objective's bound on |F|;
            # where the solution breaks the ratio, the bounds on |F| and |M| in the ratio rows; directions outside
            Fv = w[Fp.sl]
            nF = float(np.linalg.norm(Fv))
            cF, kF = Fp.centre(rF)
            pF = max(float(np.dot(cF, Fv)), _EPS)
            sF = kF * pF / max(nF, _EPS) - 1.0
            sM = 0.0
            if Mp is not None and Mp.g:
                Mv = w[Mp.sl]
                nM = float(np.linalg.norm(Mv))
                viol = 0.0
                if np.isfinite(a_hi):
                    viol = max(viol, nF / max(a_hi * nM, _EPS) - 1.0)
                if a_lo > 0:
                    viol = max(viol, a_lo * nM / max(nF, _EPS) - 1.0)
                if nM > 1e-9 * max(nF, 1.0):
                    cM, kM = Mp.centre(rM)
                    pM = max(float(np.dot(cM, Mv)), _EPS)
                    if viol > 1e-9:
                        sF = max(sF, nF / pF - 1.0, kF * pF / max(nF, _EPS) - 1.0)
                        sM = max(kM * pM / nM - 1.0, nM / pM - 1.0)
                    sM += Mp.excess(Mv)
            sF += Fp.excess(Fv)
            zF = Fp.size(rF)
            zM = Mp.size(rM) if Mp is not None else 0.0
            if zF <= exact_tol and zM <= exact_tol:
                pruned_ub = max(pruned_ub, ub)
                continue
            split_M = zM > exact_tol and (zF <= exact_tol or sM > sF or (sM == sF and zM > zF))
            kids = ([(rF, r) for r in Mp.split(rM)] if split_M else [(r, rM) for r in Fp.split(rF)])
            for kF_, kM_ in kids:
                got = node(kF_, kM_)
                nodes += 1
                if got is None:
                    continue
                if got[0] <= best * (1 + tol):
                    pruned_ub = max(pruned_ub, got[0])
                    continue
                lb_k, wl = lower(got[1])
                if lb_k > best:
                    best, best_w = lb_k, wl
                counter += 1
                heapq.heappush(heap, (-got[0], counter, (kF_, kM_), got[1]))
        upper = max(pruned_ub, -heap[0][0] if heap else 0.0, best)
        c = spec.c
        return WindowResult(c * best, c * upper, best_w, nodes, upper <= best * (1 + tol) + 1e-12)


def window_max(R, JT, fa, lb, ub, spec: WindowSpec, tol: float = 0.005, max_nodes: int = 400) -> WindowResult:
    """The maximum force over ``spec``'s window for one strength vector (see the module docstring)."""
    return WindowSolver(np.asarray(R, float), np.asarray(JT, float), np.asarray(fa, float), np.asarray(lb, float),
                        np.asarray(ub, float)).solve(spec, tol, max_nodes)


@dataclass(frozen=True)
class WindowSet:
    """The windows of all tests of an :class:`neckstrength.gap.effects.Instance` (its targets ``U6[:, 0]`` and
    force scales ``fmul[:, 0]``) at share ``share`` of the Appendix A window; ``tol``: relative bracket."""

    specs: tuple[WindowSpec, ...]
    tol: float
    planar: bool

    @staticmethod
    def make(inst, model, angle_deg: float, ratio_rel: float, share: float, tol: float) -> "WindowSet":
        Ut = model.task_direction(inst.U6[:, 0])
        dm = 1 if model.planar else 3
        return WindowSet(tuple(WindowSpec.make(Ut[k], dm, angle_deg, ratio_rel, share, inst.fmul[k, 0])
                               for k in range(len(Ut))), float(tol), bool(model.planar))

    def solve(self, R: np.ndarray, JT: np.ndarray, Fa: np.ndarray, lb: np.ndarray, ub: np.ndarray):
        """Window maxima for column strengths ``Fa`` (N x m') with bounds ``lb``/``ub`` (K x m'): forces (N x K,
        the certified lower ends), upper ends (N x K) and the wrenches (N x K x d) in the task space."""
        Fa = np.atleast_2d(Fa)
        N, K, d = len(Fa), len(self.specs), JT.shape[1]
        f = np.zeros((N, K))
        up = np.zeros((N, K))
        W = np.zeros((N, K, d))
        for i in range(N):
            ws = WindowSolver(R, JT, Fa[i], lb[0], ub[0])
            for k, spec in enumerate(self.specs):
                if k:
                    ws.set_bounds(lb[k], ub[k])
                r = ws.solve(spec, self.tol)
                f[i, k], up[i, k], W[i, k] = r.force, r.upper, r.wrench
        return f, up, W

    def candidate(self, k: int, w: np.ndarray) -> tuple[np.ndarray, float]:
        """The 6-D unit wrench (planar: the task components in their places) along task-space wrench ``w`` of
        test ``k`` and its force per unit wrench magnitude (N)."""
        from neckstrength.model.geometry import PLANAR_INDEX
        spec = self.specs[k]
        v = w / np.linalg.norm(w)
        fmul = spec.c * float(np.linalg.norm(v[spec.dm:]))
        if self.planar:
            u6 = np.zeros(6)
            u6[PLANAR_INDEX] = v
            return u6, fmul
        return v, fmul
