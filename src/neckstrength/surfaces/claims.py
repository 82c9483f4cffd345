"""The qualitative claims of thesis Sec. 4.3-4.4, evaluated on computed strength surfaces."""

from __future__ import annotations

import numpy as np
import pandas as pd

from neckstrength.surfaces.surfaces import Surface

# kinematic DOF of the variants (Sec. 4.2.1.2): spatial 3 per joint, planar 1 per joint
KINEMATIC_DOF = {"s7": 21, "s3": 9, "s2": 6, "p7": 7, "p3": 3, "p2": 2}


# "low number of muscles" for a given number of DOF: fewer than one agonist-antagonist pair of groups per DOF (a
# set of m actuators can positively span n torque directions only if m >= n + 1; a pair per DOF is the usual
# architecture). Fixed before looking at which variants fail.
MUSCLES_PER_DOF = 2


def variant_dof(variant: str) -> int | None:
    return KINEMATIC_DOF.get(str(variant).split("-", 1)[0])


def _strength(surfaces: dict[str, Surface], variant: str, factor: float) -> pd.Series:
    s = surfaces[variant].strength
    return s[np.isclose(s["factor"], factor)].set_index("direction")["force_N"]


def evaluate_claims(surfaces: dict[str, Surface], directions: pd.DataFrame, reference: str,
                    slopes: pd.DataFrame | None, tol_rel: float = 0.01,
                    anterior_max_azimuth_deg: float = 90.0, majority: float = 0.5) -> pd.DataFrame:
    """Turn each qualitative claim of Sec. 4.3-4.4 into a computed check.

    Each row: claim, thesis section, variants used, holds (True/False/None = not evaluated),
    and the numbers behind the verdict.
    """
    rows = []

    def add(claim, section, variants, holds, numbers):
        rows.append({"claim": claim, "section": section, "variants": variants,
                     "holds": None if holds is None else bool(holds), "numbers": numbers})

    d = directions.set_index("name")
    have = set(surfaces)
    if reference in have:
        s0, s1, s2 = (_strength(surfaces, reference, f) for f in (0.0, 1.0, 2.0))
        anterior = [n for n in s1.index if abs(d.loc[n, "azimuth_deg"]) < anterior_max_azimuth_deg]
        rel = ((s2 - s0).abs() / s1)[anterior]
        add("deep-extensor strength does not change strength in directions anterior to the mid-coronal line",
            "4.3.2", reference, bool((rel <= tol_rel).all()),
            f"max |F(2x)-F(0x)|/F(1x) over {len(anterior)} anterior directions = {rel.max():.4f} "
            f"({rel.idxmax()}); tolerance {tol_rel}")
        st0 = surfaces[reference].strength
        st0 = st0[np.isclose(st0["factor"], 0.0)]
        ok = (st0["status"] == "optimal") & (st0["force_N"] > 0)
        add("with 0x deep extensors every direction can still be produced", "4.4", reference, bool(ok.all()),
            f"{int(ok.sum())}/{len(ok)} directions producible at 0x; min force {st0['force_N'].min():.1f} N "
            f"({st0.loc[st0['force_N'].idxmin(), 'direction']})")
        gain = (s2 - s0)
        post = [n for n in gain.index if abs(d.loc[n, "azimuth_deg"]) > anterior_max_azimuth_deg]
        best = gain.idxmax()
        add("deep extensors matter most in the mid-sagittal posterior directions", "4.3.2", reference,
            bool(d.loc[best, "sagittal"] and best in post),
            f"largest gain F(2x)-F(0x) = {gain.max():.1f} N in '{best}'; "
            f"mean gain posterior {gain[post].mean():.1f} N vs anterior {gain[anterior].mean():.1f} N")
        act = surfaces[reference].activation
        mfR = act[np.isclose(act["factor"], 1.0) & (act["muscle"] == "mf-R")].set_index("direction")["alpha"]
        if len(mfR):
            top = mfR.idxmax()
            add("right deep extensors are most active in posterior mid-sagittal directions (Fig. 4.3)", "4.3.1",
                reference, bool(d.loc[top, "sagittal"] and abs(d.loc[top, "azimuth_deg"]) > 90),
                f"max mf-R activation {mfR.max():.3f} in '{top}'; active (>0.01) in "
                f"{int((mfR > 0.01).sum())}/{len(mfR)} directions")
    else:
        for c in ("deep-extensor strength does not change strength anterior to the mid-coronal line",
                  "with 0x deep extensors every direction can still be produced"):
            add(c, "4.3", reference, None, f"variant {reference} not computed in this config")

    def compare(variants, claim, section):
        present = [v for v in variants if v in have]
        if len(present) < 2:
            add(claim, section, ", ".join(variants), None, "fewer than two of these variants computed")
            return
        frac = []
        for a, b in zip(present[:-1], present[1:]):
            fa, fb = _strength(surfaces, a, 1.0), _strength(surfaces, b, 1.0)
            common = fa.index.intersection(fb.index)
            frac.append((a, b, float((fa[common] <= fb[common] * (1 + 1e-9)).mean()),
                         float((fa[common] / fb[common]).median())))
        holds = all(f >= majority for _, _, f, _ in frac)
        add(claim, section, ", ".join(present), holds,
            "; ".join(f"{a} <= {b} in {100 * f:.0f}% of directions (median ratio {r:.2f})" for a, b, f, r in frac))

    compare(["s7-anatomical", "s3-anatomical", "s2-anatomical"],
            "more kinematic DOF lowers strength (spatial, anatomical grouping)", "4.3.4")
    compare(["p7-anatomical", "p3-anatomical", "p2-anatomical"],
            "more kinematic DOF lowers strength (planar, anatomical grouping)", "4.3.4")
    compare(["s3-anatomical", "s3-sagittal_axial", "s3-independent"],
            "more muscle groups raise strength (spatial 3 joints)", "4.3.4")
    compare(["s3-sagittal", "s3-anatomical"],
            "the anatomical grouping beats the sagittal grouping at (about) equal m (spatial 3 joints)", "4.3.4")
    # directions a model cannot produce (Sec. 4.3.4: "Model variants with a high number of degrees of freedom and
    # low number of muscles were unable to produce forces in some test directions"), evaluated for EVERY variant:
    # a variant with fewer than MUSCLES_PER_DOF muscle groups per kinematic DOF is predicted to fail some direction,
    # every other variant to produce all of them. Either prediction can fail.
    for v in sorted(have):
        st = surfaces[v].strength
        st = st[np.isclose(st["factor"], 1.0)]
        bad = st[st["status"] != "optimal"]
        n = variant_dof(v)
        act = surfaces[v].activation
        m = int(act.loc[np.isclose(act["factor"], 1.0), "muscle"].nunique())
        if n is None or m == 0:
            add(f"{v}: producible directions", "4.3.4", v, None, "DOF or muscle count of this variant unknown")
            continue
        few = m < MUSCLES_PER_DOF * n
        listed = f": {', '.join(bad['direction'])}" if len(bad) else ""
        if few:
            add(f"{v} (n = {n} DOF, m = {m} < {MUSCLES_PER_DOF}n) cannot produce some directions", "4.3.4", v,
                len(bad) > 0, f"{len(bad)}/{len(st)} directions not producible{listed}")
        else:
            add(f"{v} (n = {n} DOF, m = {m} >= {MUSCLES_PER_DOF}n) produces every direction", "4.3.4", v,
                len(bad) == 0, f"{len(bad)}/{len(st)} directions not producible{listed}")

    if slopes is not None:
        mf_active = None
        if reference in have:
            act = surfaces[reference].activation
            a1 = act[np.isclose(act["factor"], 1.0) & act["muscle"].str.startswith("mf")]
            mf_active = sorted(set(a1[a1["alpha"] > 0.01]["direction"]))
        cols = mf_active or list(slopes.columns)

        def slope_claim(prefix, sign, claim):
            rows_ = [m for m in slopes.index if m.split("-")[0] == prefix]
            if not rows_:
                add(claim, "4.3.3", reference, None, f"no muscle group '{prefix}' in {reference}")
                return
            sub = slopes.loc[rows_, cols]
            vals = sub.to_numpy().ravel()
            vals = vals[np.abs(vals) > 1e-9]
            frac = float((np.sign(vals) == sign).mean()) if len(vals) else float("nan")
            add(claim, "4.3.3", reference, len(vals) > 0 and frac >= majority,
                f"{prefix}: {len(vals)} non-zero slopes in {len(cols)} directions where mf is active at 1x; "
                f"{100 * frac:.0f}% have sign {'+' if sign > 0 else '-'}; mean slope {np.mean(vals) if len(vals) else 0:.2e}"
                " per N")

        slope_claim("semicap", -1, "deep-extensor weakness raises semispinalis capitis activation (negative slope)")
        slope_claim("Lcap", -1, "deep-extensor weakness raises longus capitis activation (negative slope)")
        slope_claim("subocc", +1, "deep-extensor weakness lowers suboccipital activation (positive slope)")
    out = pd.DataFrame(rows)
    out["verdict"] = out["holds"].map({True: "holds", False: "does not hold", None: "not evaluated"})
    return out
