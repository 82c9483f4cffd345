"""Pipeline stages of ``workflow/rules/chapter4.smk``: strength surfaces, Figs. 4.3-4.8, claims."""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np
import pandas as pd

from neckstrength.config import chapter4_factors, full_model_from_config
from neckstrength.io import atomic_write_csv
from neckstrength.pipeline.common import load_directions


def chapter4_surface(config: Mapping, kinematic: str, muscles: str, directions_csv: str | Path,
                           out_strength: str | Path, out_activation: str | Path) -> None:
    from neckstrength.surfaces.surfaces import deep_extensor_mask, strength_surface

    full = full_model_from_config(config)
    mask = deep_extensor_mask(full, config["data"]["thesis_dir"], config["chapter4"]["deep_extensor_group"])
    surf = strength_surface(full, kinematic, muscles, load_directions(directions_csv), chapter4_factors(config),
                            mask, config["data"]["thesis_dir"], config["model"]["signature_tol_m"])
    mf = float(full.strengths[mask].sum())
    hdr = [f"Chapter 4 strength surface of {kinematic}-{muscles}: deep extensors (Table B.2 group "
           f"'{config['chapter4']['deep_extensor_group']}', {int(mask.sum())} elements, {mf:.1f} N summed) x factor",
           "force_N = max force at the test point (N); wrench = LP magnitude; status: optimal / zero (cannot produce)"]
    atomic_write_csv(surf.strength, out_strength, hdr, float_format="%.6g")
    atomic_write_csv(surf.activation, out_activation, hdr, float_format="%.5g")


def _load_surface(strength_csv, activation_csv):
    from neckstrength.surfaces.surfaces import Surface

    return Surface(pd.read_csv(strength_csv, comment="#"), pd.read_csv(activation_csv, comment="#"))


def _mf_strength_map(config: Mapping, factors) -> dict[float, float]:
    from neckstrength.surfaces.surfaces import deep_extensor_mask

    full = full_model_from_config(config)
    mask = deep_extensor_mask(full, config["data"]["thesis_dir"], config["chapter4"]["deep_extensor_group"])
    total = float(full.strengths[mask].sum())
    return {float(f): float(f) * total for f in factors}


def chapter4_reference_figures(config: Mapping, directions_csv, strength_csv, activation_csv,
                                     out_slopes, fig43, fig44, fig45, fig46) -> None:
    from neckstrength.plotting import heatmap, radar_grid_series
    from neckstrength.surfaces.plots import muscle_radars
    from neckstrength.surfaces.surfaces import activation_slopes

    ref = config["chapter4"]["reference_variant"]
    d = load_directions(directions_csv)
    surf = _load_surface(strength_csv, activation_csv)
    act, st = surf.activation, surf.strength
    a1 = act[np.isclose(act["factor"], 1.0)]
    radar_grid_series(d, [("mf-R activation (1x)", a1[a1.muscle == "mf-R"].set_index("direction")["alpha"],
                           {"color": "red", "lw": 2})], fig43,
                      f"Fig. 4.3: right deep-extensor activation, {ref}", rmax=1.0)
    series = []
    for f, c in zip(config["chapter4"]["factors"], ["purple", "blue", "green", "orange", "brown"]):
        s = st[np.isclose(st["factor"], f)].set_index("direction")["force_N"]
        series.append((f"deep extensors {f:g}x", s, {"color": c, "lw": 1.5}))
    radar_grid_series(d, series, fig44, f"Fig. 4.4: neck strength (N) vs deep-extensor strength, {ref}")
    slopes = activation_slopes(act, _mf_strength_map(config, act["factor"].unique()))
    out = slopes.reset_index().rename(columns={"index": "muscle"})
    atomic_write_csv(out, out_slopes, [f"Fig. 4.5 data: slope of activation vs bilateral deep-extensor strength "
                                       f"(per N), {ref}, factors {sorted(act['factor'].unique().tolist())}"],
                     float_format="%.4g")
    heatmap(slopes, fig45, f"Fig. 4.5: slope of activation vs bilateral deep-extensor strength, {ref}",
            "activation per N")
    a0 = act[np.isclose(act["factor"], 0.0)]
    t1 = a1.pivot(index="muscle", columns="direction", values="alpha").loc[list(dict.fromkeys(a1.muscle))]
    t0 = a0.pivot(index="muscle", columns="direction", values="alpha").loc[t1.index]
    for plane, suffix in (("sagittal_mid", "a_sagittal_mid"), ("coronal_posterior", "b_coronal_posterior")):
        names = [r["name"] for r in d.to_dict("records") if plane in r["planes"].split(";")]
        target = str(fig46).replace(".png", f"_{suffix}.png") if suffix.startswith("b") else fig46
        muscle_radars(names, [("1x deep extensors", t1, {"color": "green"}),
                              ("0x deep extensors", t0, {"color": "purple"})], target,
                      f"Fig. 4.6: activations at 1x vs 0x deep extensors, {plane.replace('_', ' ')}, {ref}")


def chapter4_complexity_figures(config: Mapping, surfaces: Mapping[str, tuple[str, str]], directions_csv,
                              fig47, fig48) -> None:
    from neckstrength.surfaces.plots import stacked_share_bars

    d = load_directions(directions_csv)
    strengths = {v: pd.read_csv(s, comment="#") for v, (s, _) in surfaces.items()}

    def table(variants, factor):
        cols = {}
        for v in variants:
            s = strengths[v]
            cols[v] = s[np.isclose(s["factor"], factor)].set_index("direction")["force_N"]
        df = pd.DataFrame(cols)
        order = [n for n in d["name"] if n in df.index]
        return df.loc[order]

    def panels(groups):
        out = []
        for title, variants in groups:
            vs = [v for v in variants if v in strengths]
            if vs:
                out.append((title, vs, table(vs, 1.0), table(vs, 0.0)))
        return out

    p47 = panels([("spatial (anatomical grouping)", ["s7-anatomical", "s3-anatomical", "s2-anatomical"]),
                  ("planar (anatomical grouping)", ["p7-anatomical", "p3-anatomical", "p2-anatomical"])])
    p48 = panels([("spatial 3 joints", ["s3-independent", "s3-sagittal_axial", "s3-sagittal", "s3-anatomical"]),
                  ("planar 3 joints", ["p3-independent", "p3-sagittal", "p3-anatomical"])])
    stacked_share_bars(p47 or [("no variants", [], pd.DataFrame(), pd.DataFrame())], fig47,
                       "Fig. 4.7: kinematic complexity; dark = deep-extensor contribution")
    stacked_share_bars(p48 or [("no variants", [], pd.DataFrame(), pd.DataFrame())], fig48,
                       "Fig. 4.8: muscle complexity; dark = deep-extensor contribution")


def chapter4_claims(config: Mapping, surfaces: Mapping[str, tuple[str, str]], directions_csv, slopes_csv,
                          out_csv) -> pd.DataFrame:
    from neckstrength.surfaces.claims import evaluate_claims

    c = config["chapter4"]
    d = load_directions(directions_csv)
    surfs = {v: _load_surface(s, a) for v, (s, a) in surfaces.items()}
    slopes = pd.read_csv(slopes_csv, comment="#").set_index("muscle")
    claims = evaluate_claims(surfs, d, c["reference_variant"], slopes, c["claim_tolerance_rel"],
                             c["anterior_max_azimuth_deg"])
    atomic_write_csv(claims, out_csv, ["Chapter 4 qualitative claims (Sec. 4.3-4.4) as computed checks",
                                       f"geometry: reconstructed test points; seed {config.get('seed')}"])
    for r in claims.to_dict("records"):
        print(f"[{r['verdict']}] {r['claim']}: {r['numbers']}")
    return claims
