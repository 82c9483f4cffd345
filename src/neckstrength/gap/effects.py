"""Candidate unmodelled effects: a registry of model extensions with a few bounded, physical parameters.

The base model is a reduced model of :mod:`neckstrength.model` in the max-wrench LP of Eq. 4.1 / 5.2.
An effect turns it into a richer :class:`Instance`: more LP rows (joints, anchors), more columns
(finer muscle units, passive torques, anchors), other activation bounds, other joint centres, other or
more wrench directions per test (the measured maximum is the largest force over a set of directions).
Every effect is **exactly** the base model at its neutral parameters (``apply`` returns the instance
unchanged there), so the extended model nests the base model.

Adding an effect is one new subclass of :class:`Effect` with a ``name``: it registers itself in
:data:`EFFECTS` (``__init_subclass__``) and is then available to the fit, the diagnosis, the benchmark,
the CLI and the pipeline (select it in ``config.yaml`` ``gap.effects``).

Effects (thesis sources in each class):

=====================  ===============================================================================
cocontraction          floor ``c`` on every muscle's activation (antagonists cannot relax fully)
cocontraction_groups   separate floors for the EMG-recorded superficial groups and for the others
direction_tolerance    the measured maximum is the largest force over the Appendix A matching window
kinematic              the 7-joint spine behind the fitted 3-/2-joint model, with passive torque capacity
asymmetry              left/right strength ratio (models whose sides are tied in the fit)
finer_groups           share of independent control of the elements inside each muscle group
origin_offset          C0-C1 (skull-frame origin) displaced from its head-pad estimate (x, y)
point_scale            test points farther from / closer to the head centre than reconstructed
shoulder_girdle        trapezius and levator scapulae pull on an unfixed scapula: shared anchor capacity
submaximal_effort      effort below 1 that varies smoothly with the push direction (one lobe)
posture_drift          head-neck flexion / extension drift during the push (shipped posture tables)
anthropometric_scaling neck size relative to the head (joint spacing and moment arms), head size at the pads
=====================  ===============================================================================
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from typing import ClassVar, Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.model.full import COORDINATES, KINEMATIC_VARIANTS, FullModel
from neckstrength.model.geometry import PLANAR_INDEX, WRENCH_COMPONENTS, jacobian_transpose
from neckstrength.model.reduction import ReducedModel


@dataclass(frozen=True)
class Param:
    """One bounded effect parameter; ``neutral`` reproduces the base model. ``shape``: a parameter of the effect's
    shape, not its size (the effort lobe's width): the power simulation's sizes keep it at ``neutral``."""

    name: str
    lo: float
    hi: float
    neutral: float
    unit: str = ""
    doc: str = ""
    shape: bool = False


@dataclass(frozen=True)
class GapContext:
    """What effects may use: the full and the fitted (base) model, and the test directions.

    ``directions``: the rows of the geometry direction table that the data set uses, in data order
    (points ``px..pz``, normals ``nx..nz``, unit wrenches ``u_*``, ``force_scale``, ``planes``).
    ``emg_groups``: base names of the model's EMG-recorded groups (config ``chapter5.emg_groups``);
    ``shoulder_muscles``: full-model base names of the muscles attached to the shoulder girdle;
    ``settings``: per-effect physical constants (config ``gap.effect_settings``). ``postures``: the shipped
    posture tables by name (:func:`neckstrength.postures.load_posture_tables`; ``posture_drift`` needs neutral and
    flex20 or ext20), ``posture_angle``: the flexion angle (deg) of the posture the directions are tested in,
    ``force_length``: config ``postures.force_length``.
    """

    full: FullModel
    model: ReducedModel
    directions: pd.DataFrame
    head_centre: np.ndarray
    emg_groups: tuple[str, ...] = ()
    shoulder_muscles: tuple[str, ...] = ("trap cl", "trap acr", "levator scap")
    tie_sides: bool = False
    settings: Mapping[str, Mapping] = field(default_factory=dict)
    postures: Mapping[str, object] | None = None
    posture_angle: float = 0.0
    force_length: str = "relative"

    @property
    def K(self) -> int:
        return len(self.directions)

    def group_base(self, j: int) -> str:
        """Model group name without the side suffix ('SCM-R' -> 'SCM')."""
        n = self.model.muscle_names[j]
        return n[:-2] if (not self.model.planar and n.endswith(("-R", "-L"))) else n

    def group_side(self, j: int) -> str:
        n = self.model.muscle_names[j]
        if self.model.planar:
            return "both"
        return "L" if n.endswith("-L") else ("R" if n.endswith("-R") else "both")


@dataclass(frozen=True)
class Instance:
    """A (possibly extended) max-wrench model for one set of test directions.

    LP rows ``rows`` (joint coordinates, then added rows), columns ``cols`` (model muscles, then added
    columns). Column strengths are affine in the base model's strengths ``f`` (m): ``A f + a0``.
    ``col_group``: the base-model muscle a column belongs to (-1: not a muscle, e.g. passive torque).
    ``elem`` (96 x m'): force of each full-model element per unit of column force (0 for non-muscles).
    ``lb``/``ub`` (K x m'): activation bounds per test direction. ``U6`` (K x J x 6) and ``fmul`` (K x J):
    J candidate unit wrenches per test and the force (N) per unit wrench magnitude along each; the
    predicted force of test k is ``max_j w*(U6[k, j]) * fmul[k, j]``, or, with ``window`` (a
    :class:`neckstrength.gap.window.WindowSet`), the maximum over each test's whole matching window (the
    candidates are then where :class:`neckstrength.gap.fit.Simulator` starts its active sets).
    ``dR`` (K x n0 x m0) and ``dJT`` (K x n0 x d), or None: a change of the first n0 rows and m0 columns of ``R``
    and of the first n0 rows of ``JT`` that differs by test (``posture_drift``: each test in its own posture), so
    that test k's LP has ``R + dR[k]`` and ``JT + dJT[k]`` (:meth:`test_matrices`); rows and columns added after it
    keep the shared values.
    """

    R: np.ndarray
    JT: np.ndarray
    row_centre: np.ndarray
    row_axis: np.ndarray
    rows: tuple[str, ...]
    A: np.ndarray
    a0: np.ndarray
    cols: tuple[str, ...]
    col_group: np.ndarray
    elem: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    P: np.ndarray
    N: np.ndarray
    U6: np.ndarray
    fmul: np.ndarray
    planar: bool
    labels: tuple[str, ...] = ()
    window: object | None = None
    dR: np.ndarray | None = None
    dJT: np.ndarray | None = None

    @property
    def muscle_cols(self) -> np.ndarray:
        return self.col_group >= 0

    @property
    def J(self) -> int:
        return self.U6.shape[1]

    def test_matrices(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Per test (K x n x m') moment arms and (K x n x d) ``J^T`` where they differ by test (``dR``), else None."""
        if self.dR is None:
            return None
        K, n0, m0 = self.dR.shape
        R = np.repeat(self.R[None], K, axis=0)
        R[:, :n0, :m0] += self.dR
        JT = np.repeat(self.JT[None], K, axis=0)
        JT[:, :n0] += self.dJT
        return R, JT

    def strengths(self, F: np.ndarray) -> np.ndarray:
        """Column strengths for base-model strength vectors ``F`` (N x m)."""
        return np.maximum(np.atleast_2d(F) @ self.A.T + self.a0[None, :], 0.0)

    def task_directions(self, model: ReducedModel) -> np.ndarray:
        """(K*J, d) unit wrenches in the model's task space, as :meth:`ReducedModel.task_direction`."""
        return model.task_direction(self.U6.reshape(-1, 6))

    def reduced(self, model: ReducedModel) -> ReducedModel:
        """This instance as a :class:`ReducedModel` for :func:`neckstrength.wrench.solve`."""
        name = model.name + ("" if not self.labels else "+" + "+".join(self.labels))
        return replace(model, name=name, coordinates=self.rows, muscle_names=self.cols,
                       strengths=self.strengths(model.strengths[None, :])[0], moment_arms=self.R, JT=self.JT,
                       S=self.elem)


def base_instance(ctx: GapContext) -> Instance:
    """The fitted model itself as an :class:`Instance` (directions and scales exactly as in the data set)."""
    model, full = ctx.model, ctx.full
    rows_idx = [COORDINATES.index(c) for c in model.coordinates]
    with np.errstate(divide="ignore", invalid="ignore"):
        elem = np.where(model.strengths[None, :] > 0,
                        full.strengths[:, None] * model.S / np.where(model.strengths > 0, model.strengths, 1)[None, :],
                        0.0)
    d = ctx.directions
    U6 = d[[f"u_{c}" for c in WRENCH_COMPONENTS]].to_numpy(float)[:, None, :]
    fmul = 1.0 / d["force_scale"].to_numpy(float)[:, None]
    K, m = len(d), model.m
    return Instance(R=model.moment_arms, JT=model.JT, row_centre=full.centres[rows_idx],
                    row_axis=full.axes[rows_idx], rows=tuple(model.coordinates), A=np.eye(m), a0=np.zeros(m),
                    cols=tuple(model.muscle_names), col_group=np.arange(m), elem=elem, lb=np.zeros((K, m)),
                    ub=np.ones((K, m)), P=d[["px", "py", "pz"]].to_numpy(float),
                    N=d[["nx", "ny", "nz"]].to_numpy(float), U6=U6, fmul=fmul, planar=model.planar)


def _add_columns(inst: Instance, R_cols: np.ndarray, A_rows: np.ndarray, a0: np.ndarray, names: Sequence[str],
                 col_group: np.ndarray | None = None, elem: np.ndarray | None = None) -> Instance:
    k = R_cols.shape[1]
    K = inst.lb.shape[0]
    return replace(inst, R=np.hstack([inst.R, R_cols]), A=np.vstack([inst.A, A_rows]), a0=np.r_[inst.a0, a0],
                   cols=inst.cols + tuple(names),
                   col_group=np.r_[inst.col_group, np.full(k, -1) if col_group is None else col_group],
                   elem=np.hstack([inst.elem, np.zeros((inst.elem.shape[0], k)) if elem is None else elem]),
                   lb=np.hstack([inst.lb, np.zeros((K, k))]), ub=np.hstack([inst.ub, np.ones((K, k))]))


def _add_rows(inst: Instance, R_rows: np.ndarray, JT_rows: np.ndarray, centres: np.ndarray, axes: np.ndarray,
              names: Sequence[str]) -> Instance:
    return replace(inst, R=np.vstack([inst.R, R_rows]), JT=np.vstack([inst.JT, JT_rows]),
                   row_centre=np.vstack([inst.row_centre, centres]), row_axis=np.vstack([inst.row_axis, axes]),
                   rows=inst.rows + tuple(names))


def _jt_rows(centres: np.ndarray, axes: np.ndarray, planar: bool) -> np.ndarray:
    JT = jacobian_transpose(centres, axes)
    return JT[:, PLANAR_INDEX] if planar else JT


def _wrench(P: np.ndarray, N: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit wrenches (K x 6) and force per unit wrench magnitude (K,) of unit forces ``N`` at points ``P``."""
    N = N / np.linalg.norm(N, axis=1, keepdims=True)
    W = np.hstack([np.cross(P, N), N])
    s = np.linalg.norm(W, axis=1)
    return W / s[:, None], 1.0 / s


#: name -> effect class; filled by :meth:`Effect.__init_subclass__`.
EFFECTS: dict[str, type["Effect"]] = {}


class Effect:
    """Base class of an unmodelled effect. Subclass it with a ``name`` to register a new effect.

    Override ``params`` (the bounded parameters, with their neutral values), ``apply`` (how the
    :class:`Instance` changes for parameters ``theta``) and optionally ``applies`` (whether the effect
    is defined for the context's model). ``defaults``: physical constants, overridable per effect in
    config ``gap.effect_settings``. ``order``: position when effects are combined (structure first,
    then strengths, geometry, bounds, directions). Effects of one ``family`` are not combined.
    """

    name: ClassVar[str] = ""
    family: ClassVar[str] = ""
    order: ClassVar[int] = 50
    description: ClassVar[str] = ""
    source: ClassVar[str] = ""
    defaults: ClassVar[dict] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if cls.name:
            EFFECTS[cls.name] = cls

    def __init__(self, ctx: GapContext, **settings):
        self.ctx = ctx
        self.s = {**self.defaults, **dict(ctx.settings.get(self.name, {}) or {}), **settings}

    # -- interface
    def params(self) -> tuple[Param, ...]:
        raise NotImplementedError

    def applies(self) -> bool:
        return True

    def apply(self, inst: Instance, theta: np.ndarray) -> Instance:
        raise NotImplementedError

    # -- helpers
    @property
    def n_params(self) -> int:
        return len(self.params())

    @property
    def neutral(self) -> np.ndarray:
        return np.array([p.neutral for p in self.params()], float)

    @property
    def lower(self) -> np.ndarray:
        return np.array([p.lo for p in self.params()], float)

    @property
    def upper(self) -> np.ndarray:
        return np.array([p.hi for p in self.params()], float)

    def is_neutral(self, theta: np.ndarray) -> bool:
        return bool(np.all(np.asarray(theta, float) == self.neutral))

    def clip(self, theta: np.ndarray) -> np.ndarray:
        return np.clip(np.asarray(theta, float), self.lower, self.upper)

    def grid(self, n: int) -> list[np.ndarray]:
        """Neutral first, then a product grid (n values for one parameter, fewer per axis for more),
        ordered by distance from neutral (relative to each parameter's range)."""
        ps = self.params()
        k = n if len(ps) == 1 else max(2, int(round(n ** (1.0 / len(ps)))) + 1)
        axes = [np.unique(np.r_[np.linspace(p.lo, p.hi, k), p.neutral]) for p in ps]
        pts = [np.array(t, float) for t in itertools.product(*axes)]
        span = np.maximum(self.upper - self.lower, 1e-12)
        pts.sort(key=lambda t: (float(np.linalg.norm((t - self.neutral) / span)), tuple(t)))
        if not self.is_neutral(pts[0]):
            pts.insert(0, self.neutral)
        return pts

    def describe(self, theta: np.ndarray) -> str:
        return ", ".join(f"{p.name}={v:.3g}{(' ' + p.unit) if p.unit else ''}"
                         for p, v in zip(self.params(), np.asarray(theta, float)))


def available_effects(ctx: GapContext, names: Sequence[str] | None = None) -> list[Effect]:
    """Instantiated effects (registry order, or the order of ``names``) that apply to ``ctx``'s model."""
    names = list(EFFECTS) if names is None else list(names)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"unknown effects {unknown}; registered: {sorted(EFFECTS)}")
    effs = [EFFECTS[n](ctx) for n in names]
    return [e for e in effs if e.applies()]


def compose(ctx: GapContext, effects: Sequence[Effect], thetas: Sequence[np.ndarray],
            base: Instance | None = None) -> Instance:
    """Apply ``effects`` with parameters ``thetas`` to the base instance, in effect ``order``."""
    inst = base_instance(ctx) if base is None else base
    for e, th in sorted(zip(effects, thetas), key=lambda et: et[0].order):
        th = np.asarray(th, float)
        if np.any(th < e.lower - 1e-12) or np.any(th > e.upper + 1e-12):
            raise ValueError(f"{e.name}: parameters {th} outside bounds [{e.lower}, {e.upper}]")
        if e.is_neutral(th):
            continue
        inst = e.apply(inst, th)
        inst = replace(inst, labels=inst.labels + (f"{e.name}({e.describe(th)})",))
    return inst


def effect_label(names: Sequence[str]) -> str:
    """Candidate label: 'none' for the base model, effect names joined by '+' otherwise."""
    return "+".join(names) if names else "none"


def parse_label(label: str) -> list[str]:
    return [] if label == "none" else label.split("+")


class CoContraction(Effect):
    """Floor ``c`` on the activation of every muscle (Sec. 5.4, Appendix A.1: the measured co-activation
    of the superficial muscles was far above the model's, which lets antagonists relax to zero).

    ``alpha_lb = c``: agonists are above it anyway, antagonists are held at ``c`` and their torque has to
    be overcome. Large floors make directions infeasible (w = 0): with s3m24 at baseline strengths a floor of
    0.15 on all 24 groups already leaves half of the 25 directions unproducible, hence the bound."""

    name = "cocontraction"
    family = "cocontraction"
    order = 60
    description = "floor on every muscle's activation (antagonist co-contraction)"
    source = "Sec. 5.4; Appendix A.1 (Figs. A.5-A.13: more co-activation than the model)"
    defaults = {"max_floor": 0.15}

    def params(self):
        return (Param("floor", 0.0, float(self.s["max_floor"]), 0.0, "", "activation floor of every muscle"),)

    def apply(self, inst, theta):
        lb = inst.lb.copy()
        mc = inst.muscle_cols
        lb[:, mc] = np.maximum(lb[:, mc], theta[0])
        return replace(inst, lb=lb, ub=np.maximum(inst.ub, lb))


class CoContractionGroups(Effect):
    """Separate activation floors for the EMG-recorded superficial groups (SCM, trapezius, splenius and
    semispinalis capitis, levator scapulae; Table A.1) and for all other groups."""

    name = "cocontraction_groups"
    family = "cocontraction"
    order = 60
    description = "activation floors per muscle class (EMG-recorded superficial groups / others)"
    source = "Sec. 5.4; Appendix A (Table A.1 muscles)"
    defaults = {"max_floor_superficial": 0.4, "max_floor_other": 0.15}

    def params(self):
        return (Param("floor_superficial", 0.0, float(self.s["max_floor_superficial"]), 0.0, "",
                      "floor of the EMG-recorded groups"),
                Param("floor_other", 0.0, float(self.s["max_floor_other"]), 0.0, "", "floor of the other groups"))

    def _superficial(self, inst: Instance) -> np.ndarray:
        emg = set(self.ctx.emg_groups)
        return np.array([g >= 0 and self.ctx.group_base(int(g)) in emg for g in inst.col_group])

    def applies(self):
        return bool(self.ctx.emg_groups)

    def apply(self, inst, theta):
        lb = inst.lb.copy()
        sup = self._superficial(inst)
        other = inst.muscle_cols & ~sup
        lb[:, sup] = np.maximum(lb[:, sup], theta[0])
        lb[:, other] = np.maximum(lb[:, other], theta[1])
        return replace(inst, lb=lb, ub=np.maximum(inst.ub, lb))


class DirectionTolerance(Effect):
    """The measured maximum may lie off the target wrench (Appendix A): the participant matched the target
    within 20 degrees in the moment and force unit vectors and 10% in the force-moment ratio
    ``R_fm = |F| / (|M| + |F|)`` (Eq. A.2), and maximised the magnitude inside that window.

    Model: the predicted force of a test is the largest force ``|F|`` (N) over a share ``s`` of the window
    (angle ``s * 20`` degrees, ratio ``rfm (1 -+ s * 10%)``). ``method: exact`` (the default) takes the maximum
    over the whole window, certified within ``tol`` (relative) by branch and bound over LPs
    (:mod:`neckstrength.gap.window`). ``method: points`` takes it over 11 candidate wrenches only: the target,
    the moment direction tilted by ``s * 20`` degrees about two perpendicular axes (+-), the force direction
    likewise, and ``R_fm`` scaled by ``1 +- s * 10%`` (planar models: in-plane force tilt x ratio, 3 x 3 = 9
    candidates), an inner approximation that can only underestimate the maximum (kept for comparison; the
    exact method starts from these candidates)."""

    name = "direction_tolerance"
    family = "tolerance"
    order = 90
    description = "measured maximum = largest force inside the Appendix A direction-matching window"
    source = "Appendix A (20 deg unit-vector error, 10% force-moment ratio error, Eq. A.2)"
    defaults = {"angle_deg": 20.0, "ratio_rel": 0.10, "method": "exact", "tol": 0.005}

    def params(self):
        return (Param("window_share", 0.0, 1.0, 0.0, "", "share of the Appendix A window used"),)

    @staticmethod
    def _perp(v: np.ndarray, hint: np.ndarray) -> np.ndarray:
        e = hint - np.dot(hint, v) * v
        if np.linalg.norm(e) < 1e-9:
            alt = np.array([1.0, 0.0, 0.0]) if abs(v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            e = alt - np.dot(alt, v) * v
        return e / np.linalg.norm(e)

    def candidates(self, u: np.ndarray, share: float, planar: bool) -> tuple[np.ndarray, np.ndarray]:
        """Candidate unit wrenches (J x 6) and force per unit wrench (J,) around unit wrench ``u``."""
        a = np.radians(float(self.s["angle_deg"]) * share)
        q = float(self.s["ratio_rel"]) * share
        M, F = u[:3], u[3:]
        m0, f0 = np.linalg.norm(M), np.linalg.norm(F)
        Mh = M / m0 if m0 > 1e-12 else np.zeros(3)
        Fh = F / f0
        rfm = f0 / (m0 + f0)

        def make(Mdir, Fdir, r):
            r = float(np.clip(r, 0.0, 1.0))
            fm, mm = r, 1.0 - r          # magnitudes with the requested ratio (overall scale irrelevant)
            if m0 <= 1e-12:
                mm = 0.0
            v = np.r_[mm * Mdir, fm * Fdir]
            nv = np.linalg.norm(v)
            return v / nv, fm / nv

        out = []
        if planar:
            z = np.array([0.0, 0.0, 1.0])
            for ang in (-a, 0.0, a):
                Fr = np.cos(ang) * Fh + np.sin(ang) * np.cross(z, Fh)
                for r in (rfm * (1 - q), rfm, rfm * (1 + q)):
                    out.append(make(Mh, Fr, r))
            # put the target first
            out.insert(0, out.pop(4))
            return np.array([o[0] for o in out]), np.array([o[1] for o in out])
        out.append(make(Mh, Fh, rfm))
        if m0 > 1e-12:
            e1 = self._perp(Mh, Fh)
            e2 = np.cross(Mh, e1)
            for e in (e1, -e1, e2, -e2):
                out.append(make(np.cos(a) * Mh + np.sin(a) * e, Fh, rfm))
        else:
            out += [make(Mh, Fh, rfm)] * 4
        g1 = self._perp(Fh, Mh if m0 > 1e-12 else np.array([0.0, 1.0, 0.0]))
        g2 = np.cross(Fh, g1)
        for g in (g1, -g1, g2, -g2):
            out.append(make(Mh, np.cos(a) * Fh + np.sin(a) * g, rfm))
        out.append(make(Mh, Fh, rfm * (1 - q)))
        out.append(make(Mh, Fh, rfm * (1 + q)))
        return np.array([o[0] for o in out]), np.array([o[1] for o in out])

    def apply(self, inst, theta):
        if inst.J != 1:
            raise ValueError("direction_tolerance must be the last effect applied (one wrench per test)")
        U, fm = [], []
        for k in range(inst.U6.shape[0]):
            c, f = self.candidates(inst.U6[k, 0], float(theta[0]), inst.planar)
            # scale so that the target candidate reproduces the instance's force per unit wrench exactly
            U.append(c)
            fm.append(f * inst.fmul[k, 0] / f[0])
        method = str(self.s["method"])
        if method not in ("exact", "points"):
            raise ValueError(f"direction_tolerance method {method!r}: 'exact' or 'points'")
        window = None
        if method == "exact":
            from neckstrength.gap.window import WindowSet
            window = WindowSet.make(inst, self.ctx.model, float(self.s["angle_deg"]), float(self.s["ratio_rel"]),
                                    float(theta[0]), float(self.s["tol"]))
        return replace(inst, U6=np.array(U), fmul=np.array(fm), window=window)


class Kinematic(Effect):
    """Kinematic complexity (Sec. 4.3, Fig. 4.7; Sec. 7.1.2.1): the real cervical spine has 7 joints; the
    fitted model keeps 3 (or 2). Dropping a joint's rows is the same as giving it unlimited passive torque.
    The effect adds the missing joints' rows (moment arms of the same muscle groups, joint axes through
    the OpenSim joint centres) with a passive (ligament, disc, facet) torque capacity
    ``tau = tau_ref (1 - q) / q`` per coordinate: ``q = 0`` is the fitted model, ``q = 1`` the strict
    7-joint model (no passive help). ``q`` stops at ``max_share`` (0.9: tau >= 1.1 N m with tau_ref = 10 N m;
    the strict 7-joint p2m7 / s3m24 models cannot produce most test directions at all)."""

    name = "kinematic"
    family = "kinematic"
    order = 20
    description = "7-joint spine behind the fitted model; passive torque capacity at the extra joints"
    source = "Sec. 4.2.1.1, 4.3 (Fig. 4.7), 7.1.2.1"
    defaults = {"tau_ref_Nm": 10.0, "max_share": 0.9}

    def params(self):
        return (Param("stiffness_share", 0.0, float(self.s["max_share"]), 0.0, "",
                      "1 / (1 + tau / tau_ref): 0 = fitted model, 1 = strict 7-joint model"),)

    def _extra(self) -> list[str]:
        model = self.ctx.model
        joints = KINEMATIC_VARIANTS["p7" if model.planar else "s7"][1]
        axes = ("pitch",) if model.planar else ("pitch", "roll", "yaw")
        return [f"{j}_{a}" for j in joints for a in axes if f"{j}_{a}" not in model.coordinates]

    def applies(self):
        return bool(self._extra())

    def apply(self, inst, theta):
        q = float(theta[0])
        extra = self._extra()
        idx = [COORDINATES.index(c) for c in extra]
        full = self.ctx.full
        R_rows = full.moment_arms[idx] @ inst.elem            # torque per unit column force at the extra joints
        inst = _add_rows(inst, R_rows, _jt_rows(full.centres[idx], full.axes[idx], inst.planar),
                         full.centres[idx], full.axes[idx], extra)
        tau = float(self.s["tau_ref_Nm"]) * (1.0 - q) / q if q > 0 else np.inf
        n_old = inst.R.shape[0] - len(extra)
        Rc = np.zeros((inst.R.shape[0], 2 * len(extra)))
        for i in range(len(extra)):
            Rc[n_old + i, 2 * i] = 1.0
            Rc[n_old + i, 2 * i + 1] = -1.0
        names = [f"passive {c} {s}" for c in extra for s in ("+", "-")]
        return _add_columns(inst, Rc, np.zeros((Rc.shape[1], inst.A.shape[1])), np.full(Rc.shape[1], tau), names)


class Asymmetry(Effect):
    """Left-right strength asymmetry for models whose left and right strengths are tied in the fit
    (s3m24, Sec. 5.3.2.1): left groups x ``exp(a/2)``, right groups x ``exp(-a/2)`` (left/right = e^a)."""

    name = "asymmetry"
    family = "grouping"
    order = 30
    description = "left/right strength ratio on top of the tied sides"
    source = "Sec. 5.3.2.1 (left = right during sampling), Sec. 7.1.2.1 (muscle grouping)"
    defaults = {"max_log_ratio": 0.7}

    def params(self):
        m = float(self.s["max_log_ratio"])
        return (Param("log_LR_ratio", -m, m, 0.0, "", "log(left / right strength)"),)

    def applies(self):
        return (not self.ctx.model.planar) and self.ctx.tie_sides

    def apply(self, inst, theta):
        a = float(theta[0])
        A = inst.A.copy()
        for c, g in enumerate(inst.col_group):
            if g < 0:
                continue
            side = self.ctx.group_side(int(g))
            if side != "both":
                A[c] *= np.exp(a / 2) if side == "L" else np.exp(-a / 2)
        return replace(inst, A=A)


class FinerGroups(Effect):
    """Finer muscle groups than the fitted model (Sec. 4.2.1.2, 7.1.2.1): a share ``kappa`` of every
    element's strength is under independent control. Element force = ``f_i ((1 - kappa) a_g + kappa b_i)``
    with the group activation ``a_g`` and an independent activation ``b_i``; ``kappa = 0`` is the fitted
    grouping, ``kappa = 1`` fully independent elements (OpenSim's 96; planar: left+right pairs)."""

    name = "finer_groups"
    family = "grouping"
    order = 10
    description = "share of independent control of the elements inside each group"
    source = "Sec. 4.2.1.2, 4.3 (Fig. 4.8), 7.1.2.1"

    def params(self):
        return (Param("independent_share", 0.0, 1.0, 0.0, "", "share of element strength controlled "
                                                                "independently of its group"),)

    def _units(self, inst: Instance) -> list[tuple[int, np.ndarray]]:
        full, model = self.ctx.full, self.ctx.model
        units = []
        for g in range(model.m):
            members = np.nonzero(model.S[:, g] > 0)[0]
            members = [i for i in members if full.strengths[i] > 0]
            if model.planar:
                by_base: dict[str, list[int]] = {}
                for i in members:
                    by_base.setdefault(full.muscles["base"].iat[i], []).append(i)
                units += [(g, np.array(v)) for v in by_base.values()]
            else:
                units += [(g, np.array([i])) for i in members]
        return units

    def applies(self):
        return self.ctx.model.m < len(self._units(None))  # more units than groups

    def apply(self, inst, theta):
        kappa = float(theta[0])
        full, model = self.ctx.full, self.ctx.model
        units = self._units(inst)
        if inst.R.shape[1] != model.m:
            raise ValueError("finer_groups must be applied first (to the fitted model's columns)")
        A = inst.A.copy()
        A[inst.muscle_cols] *= (1.0 - kappa)
        inst = replace(inst, A=A)
        n_el = full.m
        R_cols, A_rows, elem, groups, names = [], [], [], [], []
        rows_idx = [COORDINATES.index(c) for c in model.coordinates]
        for g, members in units:
            fu = full.strengths[members].sum()
            e = np.zeros(n_el)
            e[members] = full.strengths[members] / fu
            elem.append(e)
            R_cols.append(full.moment_arms[rows_idx] @ e)
            a = np.zeros(model.m)
            a[g] = kappa * fu / model.strengths[g]
            A_rows.append(a)
            groups.append(g)
            names.append(f"{model.muscle_names[g]}/{full.names[members[0]]}")
        R_cols = np.array(R_cols).T
        R_cols = np.vstack([R_cols, np.zeros((inst.R.shape[0] - R_cols.shape[0], R_cols.shape[1]))])
        return _add_columns(inst, R_cols, np.array(A_rows), np.zeros(len(units)), names, np.array(groups),
                            np.array(elem).T)


class OriginOffset(Effect):
    """Skull-frame origin error (Appendix A: C0-C1 estimated as 8 cm anterior and 2 cm inferior to the
    lower posterior pad): the joints lie ``(dx, dy)`` from where the wrenches were resolved, i.e. all joint
    centres move by ``(dx, dy, 0)`` relative to the test points. Equivalent to one common offset of all
    test points (by ``-(dx, dy)``)."""

    name = "origin_offset"
    family = "geometry"
    order = 70
    description = "C0-C1 / joint centres displaced from the head-pad estimate (sagittal plane)"
    source = "Appendix A (C0-C1 estimated from the head pad); docs/geometry.md"
    defaults = {"max_offset_m": 0.02}

    def params(self):
        m = float(self.s["max_offset_m"])
        return (Param("dx", -m, m, 0.0, "m", "anterior offset of the joints"),
                Param("dy", -m, m, 0.0, "m", "superior offset of the joints"))

    def apply(self, inst, theta):
        d = np.array([theta[0], theta[1], 0.0])
        joint = ~np.isnan(inst.row_centre[:, 0])
        centre = inst.row_centre.copy()
        centre[joint] = centre[joint] + d
        JT = inst.JT.copy()
        JT[joint] = _jt_rows(centre[joint], inst.row_axis[joint], inst.planar)
        return replace(inst, row_centre=centre, JT=JT)


class PointScale(Effect):
    """Test-point location error: the test-point coordinates are reconstructions on an ellipsoidal head
    (docs/geometry.md). All points move radially from the head-ellipsoid centre by ``(1 + s)`` (a larger
    or smaller head), normals unchanged; unit wrenches and force scales follow."""

    name = "point_scale"
    family = "geometry_points"
    order = 75
    description = "test points radially farther from / closer to the head centre"
    source = "Appendix A (Fig. A.3 test points); docs/geometry.md (reconstruction)"
    defaults = {"max_scale": 0.15}

    def params(self):
        m = float(self.s["max_scale"])
        return (Param("radial_scale", -m, m, 0.0, "", "relative change of the point-to-head-centre distance"),)

    def apply(self, inst, theta):
        if inst.J != 1:
            raise ValueError("point_scale must be applied before direction_tolerance")
        c = np.asarray(self.ctx.head_centre, float)
        P = c + (1.0 + float(theta[0])) * (inst.P - c)
        U, fmul = _wrench(P, inst.N)
        return replace(inst, P=P, U6=U[:, None, :], fmul=fmul[:, None])


class ShoulderGirdle(Effect):
    """Trapezius and levator scapulae insert on the shoulder girdle, which the set-up did not fix (torso
    strapped, shoulders free; Appendix A). Their pull on the head is resisted at the scapula only as far as
    arm weight and scapular depressors hold it. Model: per side, the summed force of the shoulder-girdle
    elements is capped by an anchor at ``(1 - s)`` times their summed strength (one LP row and one anchor
    column per side). ``s = 0``: fixed scapula (the cap never binds). A plain strength factor would be
    absorbed exactly by the free group strengths (trap and levscap are groups of their own in s3m24);
    the shared cap is not, because the two muscles compete for it."""

    name = "shoulder_girdle"
    family = "shoulder"
    order = 40
    description = "shared anchor capacity of trapezius + levator scapulae per side (unfixed scapula)"
    source = "Appendix A (torso strapped, shoulders free); Table A.1 (trap, levator scapulae EMG)"
    defaults = {"max_release": 0.8}

    def params(self):
        return (Param("release", 0.0, float(self.s["max_release"]), 0.0, "",
                      "1 - anchor capacity / summed strength of the shoulder-girdle elements"),)

    def _elements(self) -> dict[str, np.ndarray]:
        full = self.ctx.full
        names = {n.lower() for n in self.ctx.shoulder_muscles}
        sh = np.array([b.lower() in names for b in full.muscles["base"]])
        if self.ctx.model.planar:
            return {"both": sh}
        side = full.muscles["side"].to_numpy()
        return {"R": sh & (side == "R"), "L": sh & (side == "L")}

    def applies(self):
        inst = base_instance(self.ctx)
        return any(np.any(mask @ inst.elem > 0) for mask in self._elements().values())

    def apply(self, inst, theta):
        s = float(theta[0])
        for side, mask in self._elements().items():
            coef = mask.astype(float) @ inst.elem          # element force per unit column force
            if not np.any(coef > 0):
                continue
            row = np.r_[coef, 0.0]
            # anchor column: its own coefficient -1 in the new row
            inst = _add_columns(inst, np.zeros((inst.R.shape[0], 1)), ((1 - s) * coef @ inst.A)[None, :],
                                np.array([(1 - s) * coef @ inst.a0]), [f"scapular anchor {side}"])
            row[-1] = -1.0
            inst = _add_rows(inst, row[None, :], np.zeros((1, inst.JT.shape[1])), np.full((1, 3), np.nan),
                             np.zeros((1, 3)), [f"scapular anchor {side}"])
        return inst


#: Head-neck flexion angle (deg, + flexion) of each shipped sagittal posture table (docs/postures.md).
POSTURE_ANGLES = {"ext20": -20.0, "neutral": 0.0, "flex20": 20.0}


class SubmaximalEffort(Effect):
    """Submaximal effort that differs by direction (pain, fear of pain, unfamiliarity with the direction): the
    participant activates every muscle up to ``effort(n) < 1`` of its maximum in a test whose push has unit force
    direction ``n`` (skull frame), so the measured maximum is ``effort(n)`` times the model's (exactly: with no
    activation floor the max-wrench LP is homogeneous in the upper bounds). The field is one smooth lobe of reduced
    effort around one push direction: ``effort(n) = 1 - 2|b| ((1 + n . b/|b|) / 2)^w``, the vector ``b`` (three
    parameters; planar models: two, in the sagittal plane) giving the lobe's direction and depth, norm capped at
    ``(1 - min_effort) / 2`` so that effort lies in ``[min_effort, 1]``, and ``w`` (``lobe_power``, 1 to
    ``max_lobe_power``) its width: ``w = 1`` is the broadest lobe, a dipole ``1 - |b| - b . n`` (the only shape
    before 2026-11-28), larger ``w`` a lobe that recovers full effort closer to the painful direction (``w = 4``:
    effort half-way back about 47 deg from it). A constant effort is absorbed by the free strengths exactly (the
    forces scale with them), so only the directional part can be seen; one lobe cannot absorb a misfit that varies
    faster over the directions.

    Bound: voluntary activation in maximal isometric efforts of healthy adults is about 85-100% (twitch
    interpolation; Gandevia 2001 Physiol Rev 81:1725), lower with pain or fear of pain; the set-up has no check
    of effort (Appendix A). ``min_effort`` 0.6 is a generous floor and the width's range a modelling choice; the
    user benchmark's effort truths (:mod:`neckstrength.gap.truths`) are lobes of width 2, inside this family
    (docs/gap_diagnosis.md says what that means for its score)."""

    name = "submaximal_effort"
    family = "effort"
    order = 65
    description = ("effort 1 - 2|b| ((1 + n.b/|b|) / 2)^w by push direction n (one smooth lobe, effort in "
                   "[min_effort, 1], width w)")
    source = ("Appendix A (maximal voluntary efforts, no check of effort); Gandevia 2001 Physiol Rev 81:1725 "
              "(voluntary activation of healthy adults 85-100%)")
    defaults = {"min_effort": 0.6, "max_lobe_power": 4.0}

    def _bmax(self) -> float:
        e = float(self.s["min_effort"])
        if not 0.0 < e < 1.0:
            raise ValueError(f"gap.effect_settings.submaximal_effort.min_effort: in (0, 1), not {e}")
        return (1.0 - e) / 2.0

    def params(self):
        m = self._bmax()
        w = float(self.s["max_lobe_power"])
        if not w >= 1.0:
            raise ValueError(f"gap.effect_settings.submaximal_effort.max_lobe_power: at least 1, not {w}")
        names = (("b_anterior", "b_superior") if self.ctx.model.planar
                 else ("b_anterior", "b_superior", "b_lateral"))
        return tuple(Param(n, -m, m, 0.0, "", f"lobe vector's {n[2:]} component (direction and depth)")
                     for n in names) + (Param("lobe_power", 1.0, max(w, 1.0 + 1e-9), 1.0, "",
                                              "lobe width exponent (1: a dipole, larger: narrower)", shape=True),)

    def grid(self, n: int) -> list[np.ndarray]:
        """Neutral and the points along each axis of ``b`` at width 1 (``n`` values per axis from lower to upper
        bound, neutral left out): dipoles along the skull axes, 1 + 12 = 13 points for three axes (the full product
        would have 125); oblique and narrower lobes are left to the refinement. (The corners of the box as well, 21
        points, cost 8 more fits per problem and did not change the simulated power on S003: docs/gap_diagnosis.md.)
        The width does not move the neutral point (``b = 0``: effort 1 at any width), so it has no axis here."""
        ps = self.params()[:-1]
        pts = [self.neutral]
        for a, p in enumerate(ps):
            for v in np.linspace(p.lo, p.hi, max(2, int(n))):
                if abs(v - p.neutral) > 1e-12:
                    t = self.neutral.copy()
                    t[a] = v
                    pts.append(t)
        span = np.maximum(self.upper - self.lower, 1e-12)
        pts[1:] = sorted(pts[1:], key=lambda t: (float(np.linalg.norm((t - self.neutral) / span)), tuple(t)))
        return pts

    def effort(self, N: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Effort (K,) of tests with unit force directions ``N`` (K x 3) at parameters ``theta`` (``b``, then the
        width; without the width: 1)."""
        theta = np.asarray(theta, float)
        nb_params = len(self.params()) - 1
        w = float(theta[nb_params]) if len(theta) > nb_params else 1.0
        b = np.zeros(3)
        b[:nb_params] = theta[:nb_params]
        nb = float(np.linalg.norm(b))
        m = self._bmax()
        if nb > m:
            b, nb = b * (m / nb), m
        if nb == 0.0:
            return np.ones(len(N))
        Nh = N / np.linalg.norm(N, axis=1, keepdims=True)
        c = np.clip(Nh @ (b / nb), -1.0, 1.0)
        return np.clip(1.0 - 2.0 * nb * ((1.0 + c) / 2.0) ** max(w, 1.0), 1.0 - 2.0 * m, 1.0)

    def apply(self, inst, theta):
        e = self.effort(inst.N, theta)
        ub = inst.ub.copy()
        mc = inst.muscle_cols
        ub[:, mc] = np.minimum(ub[:, mc], e[:, None])
        return replace(inst, ub=np.maximum(ub, inst.lb))


#: The axis each shipped non-neutral posture table turns about, and its joint-angle sign and size (deg, head on
#: thorax), as data/model/postures/postures.csv's ``axis`` and ``theta_deg`` (a test checks): positive pitch is
#: extension, positive roll bends to the right, positive yaw turns to the left.
POSTURE_AXES = {"flex20": ("pitch", -20.0), "ext20": ("pitch", 20.0), "bendL15": ("roll", -15.0),
                "bendR15": ("roll", 15.0), "rotL30": ("yaw", 30.0), "rotR30": ("yaw", -30.0)}


class PostureDrift(Effect):
    """The head-neck posture drifts during the push (the head is strapped to the pads, the torso to the chair, the
    neck between them is free, and pads and straps give; Appendix A): in every test the head moves ``drift``
    degrees away from the set posture in the direction of the torque the test demands of the neck (the head gives
    way in the direction it pushes). The direction per test: the demanded joint torque ``J^T u`` of the test's
    target wrench, summed over the model's joints per axis (pitch, roll, yaw) and normalised; each axis turns by
    ``drift`` times its share. The model in the drifted posture comes from the shipped posture tables
    (``data/model/postures``, docs/postures.md): element moment arms, joint centres and axes and active
    force-length factors, along pitch interpolated linearly between the two nearest of ext20, neutral and flex20
    (from the set posture, ``ctx.posture_angle``), along roll and yaw the change from neutral to bendL15 / bendR15
    and rotL30 / rotR30 scaled by the angle's share of the table's (summed over the axes: first order in the
    angles); joint axes renormalised, ``J^T`` rebuilt, then reduced with the fitted model's grouping (Sec. 4.2.1.3)
    as :func:`neckstrength.postures.model.reduce_in_posture` does; group strengths follow the force-length factors
    (``ctx.force_length``). Test points and push directions stay fixed to the skull (the pads move with the head).
    So every test has its own moment arms and ``J^T`` (``Instance.dR`` / ``dJT``); the joint centres reported
    (``row_centre``) and the element shares (``elem``: EMG, added rows) stay those of the set posture, and rows and
    columns that ``kinematic``, ``finer_groups`` or ``shoulder_girdle`` add keep the set posture's moment arms.

    Bound: 0 to 15 deg (``max_drift_deg``). The thesis does not measure how far the head moves during a test
    (Appendix A: no motion capture in the strength tests); 15 deg is the smallest range of the shipped tables
    (lateral bend), so every posture drifted from neutral lies between computed postures (from a set posture of
    flex20 / ext20, the posture tests, a pitch drift away from neutral extrapolates along the last segment). Drift
    against the push (negative) is not a candidate: compliance yields in the direction of the load."""

    name = "posture_drift"
    family = "posture"
    order = 5
    description = "head-neck posture drifts in each test along the demanded torque (shipped posture tables)"
    source = ("Appendix A (head strapped to the pads, neck free; no measurement of head motion); data/model/postures "
              "(docs/postures.md; range of the tables: flexion/extension 20 deg, lateral bend 15, axial rotation 30)")
    defaults = {"max_drift_deg": 15.0}

    def params(self):
        m = float(self.s["max_drift_deg"])
        if not 0.0 < m <= 15.0:
            raise ValueError(f"gap.effect_settings.posture_drift.max_drift_deg: in (0, 15] (the tables' smallest "
                             f"range, lateral bend), not {m}")
        return (Param("drift_deg", 0.0, m, 0.0, "deg", "posture drift per test along the torque it demands"),)

    def _axes(self) -> tuple[str, ...]:
        """The rotation axes of the model's coordinates (pitch; pitch, roll, yaw)."""
        return tuple(dict.fromkeys(c.rsplit("_", 1)[1] for c in self.ctx.model.coordinates))

    def applies(self):
        tabs = dict(self.ctx.postures or {})
        need = ["neutral"] + [p for p, (ax, _) in POSTURE_AXES.items() if ax in self._axes()]
        return all(p in tabs for p in need)

    def _pitch_tables(self) -> list[tuple[float, object]]:
        """(pitch angle, table) along pitch, ascending (ext20 is +20)."""
        tabs = dict(self.ctx.postures)
        pts = [(0.0, tabs["neutral"])] + [(ang, tabs[p]) for p, (ax, ang) in POSTURE_AXES.items() if ax == "pitch"]
        return sorted(pts, key=lambda t: t[0])

    def state(self, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Element moment arms (21 x 96), strength factors (96), joint centres and unit axes (21 x 3) at joint
        angles ``angles`` = (pitch, roll, yaw) in deg of the head on the thorax (pitch from neutral)."""
        tabs = dict(self.ctx.postures)
        fl = str(self.ctx.force_length)
        pts = self._pitch_tables()
        ang = np.array([a for a, _ in pts])
        i = int(np.clip(np.searchsorted(ang, angles[0]) - 1, 0, len(ang) - 2))
        (a0, t0), (a1, t1) = pts[i], pts[i + 1]
        w = (angles[0] - a0) / (a1 - a0)
        R = (1 - w) * t0.moment_arms + w * t1.moment_arms
        fac = (1 - w) * t0.strength_factor(fl) + w * t1.strength_factor(fl)
        c = (1 - w) * t0.centres + w * t1.centres
        ax = (1 - w) * t0.axes + w * t1.axes
        tn = tabs["neutral"]
        for a, axis in ((angles[1], "roll"), (angles[2], "yaw")):
            if a == 0.0:
                continue
            p, full_angle = next((q, v) for q, (x, v) in POSTURE_AXES.items() if x == axis and v * a > 0)
            s = a / full_angle
            t = tabs[p]
            R = R + s * (t.moment_arms - tn.moment_arms)
            fac = fac + s * (t.strength_factor(fl) - tn.strength_factor(fl))
            c = c + s * (t.centres - tn.centres)
            ax = ax + s * (t.axes - tn.axes)
        ax = ax / np.linalg.norm(ax, axis=1, keepdims=True)
        return R, np.maximum(fac, 0.0), c, ax

    def drift_angles(self, inst: Instance, drift: float) -> np.ndarray:
        """(K x 3) joint-angle change (deg; pitch, roll, yaw) of each test: ``drift`` along the axis shares of the
        torque its target wrench demands of the model's joints (``J^T u``, summed over the joints)."""
        model = self.ctx.model
        m_rows = len(model.coordinates)
        tau = inst.task_directions(model) @ inst.JT[:m_rows].T            # (K, n0): J = 1 here
        axis_of = [c.rsplit("_", 1)[1] for c in model.coordinates]
        per = np.zeros((len(tau), 3))
        for r, a in enumerate(axis_of):
            per[:, ("pitch", "roll", "yaw").index(a)] += tau[:, r]
        nrm = np.linalg.norm(per, axis=1, keepdims=True)
        return np.where(nrm > 1e-12, drift * per / np.where(nrm > 1e-12, nrm, 1.0), 0.0)

    def apply(self, inst, theta):
        from neckstrength.model.reduction import reduce_strengths_and_arms

        model, full = self.ctx.model, self.ctx.full
        m, n0 = model.m, len(model.coordinates)
        rows_idx = [COORDINATES.index(c) for c in model.coordinates]
        if inst.R.shape != (n0, m) or inst.rows != tuple(model.coordinates) or inst.J != 1:
            raise ValueError("posture_drift must be applied first (to the fitted model's rows and columns)")
        set_angles = np.array([-float(self.ctx.posture_angle), 0.0, 0.0])   # ctx.posture_angle: + flexion
        _, fac0, c0, ax0 = self.state(set_angles)
        f_set = np.where(fac0 > 0, full.strengths / np.where(fac0 > 0, fac0, 1.0), full.strengths)

        def effective(angles):
            """Moment arms x group strength ratio to the set posture (n0 x m) and J^T (n0 x d) at ``angles``."""
            R, fac, c, ax = self.state(angles)
            f_g, R_g = reduce_strengths_and_arms(R[rows_idx], f_set * fac, model.S)
            return f_g, R_g, _jt_rows(c[rows_idx], ax[rows_idx], inst.planar)

        f_g0, R_g0, JT0 = effective(set_angles)
        dang = self.drift_angles(inst, float(theta[0]))
        K = len(dang)
        dR = np.zeros((K, n0, m))
        dJT = np.zeros((K, n0, inst.JT.shape[1]))
        for k in range(K):
            f_g, R_g, JT = effective(set_angles + dang[k])
            ratio = np.where(f_g0 > 0, f_g / np.where(f_g0 > 0, f_g0, 1.0), 0.0)
            dR[k] = R_g * ratio[None, :] - R_g0
            dJT[k] = JT - JT0
        return replace(inst, dR=dR, dJT=dJT)


class AnthropometricScaling(Effect):
    """Head and neck size: the model's geometry is one (scaled) adult's (Vasavada et al. 1998 geometry behind the
    OpenSim model, docs/model_derivation.md), the participant's head and neck are their own. Two parameters:

    - ``neck_scale`` ``s``: the size of the neck relative to the head. The joint centres move away from C0-C1 by
      ``1 + s`` (``c_j -> c_0 + (1 + s)(c_j - c_0)``) and the muscles' moment arms scale by ``1 + s``. Scaling the
      head (test points, C0-C1 in the skull frame) and the neck by one common factor leaves every predicted force
      unchanged (torques and lever arms scale alike; tested), and a common factor on the moment arms alone is
      absorbed by the free strengths, so this is the neck's only free size.
    - ``head_scale`` ``h``: the head's radius at the pads, relative to the model's. The test points move
      radially from the head centre by ``1 + h`` (``P -> c + (1 + h)(P - c)``), C0-C1 and the joints stay: the
      pads rest on the skull's surface, whose distance from the head centre varies with head breadth and length
      more than the occipital condyles' position does. At ``s = 0`` this is ``point_scale`` (a reconstruction
      error of the points' radius, the same change of the forces); the two are told apart only by ``s``, and the
      Bayes evidence prefers the one-parameter ``point_scale`` where ``s`` adds nothing.

    Bounds +-15% each (``max_scale``, ``max_head_scale``): in height-matched men and women, neck dimensions differ
    by 9-16% and head dimensions by 3-6% (Vasavada, Danaraj and Siegmund 2008 J Biomech 41:114), i.e. the
    neck-to-head ratio by about 6-10% between the sexes, plus individual spread (head length and breadth SD about
    4% of their means, Pheasant and Haslegrave, Bodyspace, 3rd ed., 2006: +-15% is about 3.5 SD)."""

    name = "anthropometric_scaling"
    family = "anthropometry"
    order = 72
    description = ("neck size relative to the head (joint spacing below C0-C1 and moment arms x (1 + s)) and head "
                   "size at the pads (test points from the head centre x (1 + h))")
    source = ("Vasavada, Danaraj and Siegmund 2008 J Biomech 41:114 (head vs neck dimensions); Appendix A (C0-C1 "
              "from the head pad)")
    defaults = {"max_scale": 0.15, "max_head_scale": 0.15}

    def params(self):
        m, mh = float(self.s["max_scale"]), float(self.s["max_head_scale"])
        return (Param("neck_scale", -m, m, 0.0, "", "relative size of the neck (joint spacing, moment arms) "
                                                      "against the head"),
                Param("head_scale", -mh, mh, 0.0, "", "relative distance of the test points (pads) from the head "
                                                        "centre"))

    def _c0(self, inst: Instance) -> np.ndarray:
        top = [i for i, r in enumerate(inst.rows) if r.startswith("C0-C1_")]
        if not top:
            raise ValueError("anthropometric_scaling: the model has no C0-C1 joint")
        return inst.row_centre[top[0]]

    def applies(self):
        return any(c.startswith("C0-C1_") for c in self.ctx.model.coordinates) and len(
            {c.split("_")[0] for c in self.ctx.model.coordinates}) >= 2

    def apply(self, inst, theta):
        if inst.J != 1:
            raise ValueError("anthropometric_scaling must be applied before direction_tolerance")
        k, kh = 1.0 + float(theta[0]), 1.0 + float(theta[1])
        joint = ~np.isnan(inst.row_centre[:, 0])
        c0 = self._c0(inst).copy()
        centre = inst.row_centre.copy()
        centre[joint] = c0 + k * (centre[joint] - c0)
        JT = inst.JT.copy()
        JT[joint] = _jt_rows(centre[joint], inst.row_axis[joint], inst.planar)
        R = inst.R.copy()
        R[np.ix_(joint, inst.muscle_cols)] *= k
        out = replace(inst, R=R, JT=JT, row_centre=centre)
        if kh == 1.0:
            return out
        c = np.asarray(self.ctx.head_centre, float)
        P = c + kh * (inst.P - c)
        U, fmul = _wrench(P, inst.N)
        return replace(out, P=P, U6=U[:, None, :], fmul=fmul[:, None])
