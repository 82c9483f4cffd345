"""Pipeline stages of ``workflow/rules/reruns.smk``: run-to-run distributions of the thesis's estimates (issue 36).

``reruns_members``: K members of one chapter x model x data set (:mod:`neckstrength.reruns.runs`), one long
table; ``reruns_bands``: every printed cell of Tables 5.1-5.3 and 6.1 beside our members' central band.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from neckstrength.config import (
    abc_settings,
    chapter6_settings,
    dataset_from_config,
    full_model_from_config,
    model_from_config,
    rerun_settings,
)
from neckstrength.estimation.datasets import thesis_result_table
from neckstrength.io import atomic_write_csv
from neckstrength.pipeline.chapter6 import chapter6_dataset
from neckstrength.pipeline.common import load_directions
from neckstrength.reruns.bands import band_table
from neckstrength.reruns.runs import algorithm4_member, member_stream, sequential_member
from neckstrength.seeds import generator

CHAPTER_TABLES = {"chapter5": {"p2m7": "Table 5.1", "p3m12": "Table 5.2", "s3m24": "Table 5.3"},
                  "chapter6": {"p2m7": "Table 6.1"}}


def reruns_members(config: Mapping, chapter: str, model_name: str, dataset: str, directions_csv: str | Path,
                   out_csv: str | Path) -> pd.DataFrame:
    """K members (``reruns.<chapter>.members``) of the chapter's estimator on one model x data set."""
    rs = rerun_settings(config, chapter, model_name)
    K = rs.members
    model = model_from_config(full_model_from_config(config), config, model_name)
    d = load_directions(directions_csv)
    if chapter == "chapter5":
        c = config["chapter5"]
        data = dataset_from_config(config, "chapter5", model, d, dataset)
        settings = abc_settings(config, model_name)
        what = f"Algorithm 4 (Chapter 5), settings {settings}; Eq. 5.3 scaling '{c['bootstrap_direction']}'"
    elif chapter == "chapter6":
        data = chapter6_dataset(model, d, dataset, config)
        over = {} if rs.n_candidates is None else {"n_candidates": rs.n_candidates}
        settings = chapter6_settings(config, model_name, **over)
        what = f"Table 6.1's posterior after every test (Algorithms 7-8), settings {settings}"
    else:
        raise ValueError(f"unknown chapter {chapter!r} (chapter5, chapter6)")
    frames = []
    for k in range(K):
        stream, text = member_stream(config["seed"], chapter, model_name, dataset, k)
        t0 = time.time()
        if chapter == "chapter5":
            m = algorithm4_member(model, data, settings, config["chapter5"]["bootstrap_direction"],
                                  generator(stream))
        else:
            m = sequential_member(model, data, settings, stream)
        dt = time.time() - t0
        m.insert(0, "member", k)
        m.insert(0, "dataset", dataset)
        m.insert(0, "model", model_name)
        m["stream"] = text
        m["seconds"] = dt
        frames.append(m)
        print(f"{chapter} {model_name}/{dataset} member {k} ({text}): {dt:.1f} s", flush=True)
    out = pd.concat(frames, ignore_index=True)
    atomic_write_csv(out, out_csv, [f"run-to-run members of {what}: model {model_name}, data set {dataset}, "
                                    f"K = {K}",
                                    "member 0 = the pipeline's own run (its random stream); member k >= 1: "
                                    "SeedSequence([seed, crc32('reruns/<chapter>/<model>/<dataset>'), k]) "
                                    "(neckstrength.reruns.runs.STREAM_KEYS); seconds = wall time of the member"],
                     float_format="%.6g")
    return out


def thesis_with_text(thesis_dir: str | Path, model_name: str, table: str | None = None) -> pd.DataFrame:
    """:func:`thesis_result_table` with ``value`` as the printed text (digits kept: '0.20', '30+')."""
    from neckstrength.estimation.datasets import RESULT_TABLES

    t = thesis_result_table(thesis_dir, model_name, table)
    raw = pd.read_csv(Path(thesis_dir) / (table or RESULT_TABLES[model_name]), comment="#", dtype={"value": str})
    t["value"] = raw["value"].to_numpy()
    t.insert(0, "model", model_name)
    return t


def reruns_bands(config: Mapping, chapter: str, member_csvs: Sequence[str | Path], out_csv: str | Path
                 ) -> pd.DataFrame:
    """Every printed cell of the chapter's tables that has members, beside our central band."""
    members = pd.concat([pd.read_csv(p, comment="#", keep_default_na=False, na_values=[""]) for p in member_csvs],
                        ignore_index=True)
    members["parameter"] = members["parameter"].fillna("").astype(str)
    level = float(config["reruns"]["level"])
    table = config["chapter6"]["thesis_table"] if chapter == "chapter6" else None
    thesis = pd.concat([thesis_with_text(config["data"]["thesis_dir"], m, table)
                        for m in members["model"].unique()], ignore_index=True)
    bands = band_table(members, thesis, level)
    bands.insert(0, "table", [CHAPTER_TABLES[chapter].get(m, "") for m in bands["model"]])
    bands.insert(0, "chapter", {"chapter5": "Chapter 5", "chapter6": "Chapter 6"}[chapter])
    k = members.groupby(["model", "dataset"])["member"].nunique()
    atomic_write_csv(bands, out_csv, [f"{chapter}: every printed cell beside the central {level:.0%} band of our "
                                      f"K members (K per model x data set: "
                                      + ", ".join(f"{m}/{d} {n}" for (m, d), n in k.items()) + ")",
                                      "spread = half width of the band; print_reproducible = spread <= half a unit "
                                      "of the last printed digit; seed " + str(config["seed"])],
                     float_format="%.6g")
    return bands


def report_distribution(config: Mapping, band_csvs: Sequence[str | Path], scorecard_csv: str | Path, out_table,
                        out_summary, out_spread) -> pd.DataFrame:
    """The run-to-run scoring rule: every Chapter 5 / 6 item against our band, the summary per table and the
    seed-to-seed spread per muscle group."""
    from neckstrength.report.scorecard.distribution import CONSISTENT, group_spread, score_distribution

    bands = pd.concat([pd.read_csv(p, comment="#", keep_default_na=False, na_values=[""]) for p in band_csvs],
                      ignore_index=True)
    scorecard = pd.read_csv(scorecard_csv, comment="#")
    table, summary = score_distribution(bands, scorecard, int(config["seed"]))
    level = float(config["reruns"]["level"])
    k = f"{int(bands['members'].min())}-{int(bands['members'].max())}" if len(bands) else "0"
    hdr = [f"run-to-run scoring (issue 36): each printed Chapter 5 / 6 value against the central {level:.0%} band of "
           f"our K = {k} reruns (results/reruns/<chapter>/bands.csv), widened by half a unit of the printed digit",
           f"verdicts: '{CONSISTENT}' (inside) / 'outside our band'; chance rate = share 'consistent' when the bands "
           "are permuted among the items of a stratum (table x quantity x data set), mean over seeded permutations; "
           f"seed {config['seed']}",
           "Algorithm 4 (Chapter 5) draws nothing at random: its members are identical, so its band is a point and "
           "any difference from the print comes from an input or a choice, not from the run"]
    atomic_write_csv(table, out_table, hdr, float_format="%.5g")
    atomic_write_csv(summary, out_summary, hdr[:2], float_format="%.4g")
    atomic_write_csv(group_spread(bands), out_spread,
                     ["seed-to-seed spread of f_c per muscle group: half width of our central band relative to the "
                      "median, median and largest over the data sets; beside it the printed half unit relative to "
                      "the printed value (where the spread is wider, the printed digits are not reproducible)"],
                     float_format="%.4g")
    print(summary.to_string(index=False))
    return table


def _variants(config: Mapping, section: Mapping) -> dict:
    """'baseline' (no change) and the variants of ``section`` (a ``reruns.attribution`` block), in config order."""
    from neckstrength.config import ConfigError, plain

    variants = {"baseline": {}}
    for v in plain(section["variants"]):
        if v["name"] in variants:
            raise ConfigError("reruns.attribution.variants", [f"variant name {v['name']!r} used twice"])
        variants[v["name"]] = v["set"]
    return variants


def _attribution_runs(config: Mapping, variants: Mapping, sections: Sequence[str], run_variant
                      ) -> tuple[list[pd.DataFrame], dict]:
    """For each variant: the config with its changes (validated, defaults filled), then ``run_variant(cfg)``, a
    members table; a variant whose changed input makes no model / data set is 'not evaluated' with the reason."""
    import json

    from neckstrength.config import ConfigError, plain, validate_config
    from neckstrength.errors import DataValidationError
    from neckstrength.reruns.attribution import apply_variant

    base = {k: plain(config[k]) for k in sections}
    frames, failed = [], {}
    for name, changes in variants.items():
        try:
            cfg = validate_config(apply_variant(base, name, changes), source=f"reruns.attribution.variants.{name}")
        except KeyError as e:
            raise ConfigError(f"reruns.attribution.variants.{name}", [str(e).strip("'\"")]) from None
        t0 = time.time()
        try:
            members = run_variant(cfg)
        except (DataValidationError, ValueError) as e:  # the changed input makes no model / data set: say why
            if name == "baseline":
                raise
            failed[name] = f"not evaluated: {type(e).__name__}: {e}"
            print(f"variant {name} {json.dumps(changes)}: {failed[name]}", flush=True)
            continue
        frames.append(members.assign(variant=name))
        print(f"variant {name} {json.dumps(changes)}: {time.time() - t0:.1f} s", flush=True)
    return frames, failed


def _write_attribution(config: Mapping, variants: Mapping, frames: Sequence[pd.DataFrame], failed: Mapping,
                       thesis: pd.DataFrame, out_runs, out_summary, hdr0: str) -> pd.DataFrame:
    import json

    from neckstrength.report.scorecard.distribution import attribution_summary

    level = float(config["reruns"]["level"])
    bands = []
    for f in frames:
        b = band_table(f.drop(columns=["variant"]), thesis, level)
        b.insert(0, "variant", f["variant"].iloc[0])
        bands.append(b)
    items, summary = attribution_summary(pd.concat(bands, ignore_index=True),
                                         {k: json.dumps(v) for k, v in variants.items()})
    summary = pd.concat([summary, pd.DataFrame([{"variant": k, "changes": json.dumps(variants[k]), "note": why}
                                                for k, why in failed.items()])], ignore_index=True)
    summary = summary.set_index("variant").loc[list(variants)].reset_index()   # config order
    hdr = [hdr0,
           "ours = the members' median; on_print = within half a unit of the printed digit; inside_band = inside our "
           f"central {level:.0%} band widened by half a printed unit; within_tolerance = the scorecard's 'matches' "
           "test (f_c max(0.5 N, 10 %), sigma_c 0.05, v_c max(0.5 N^2, 21 %), D(f_c) 0.01, iterations max(1, 20 %)); "
           "moved_onto / moved_off = items within tolerance with the change and not at baseline / the reverse; "
           f"seed {config['seed']}"]
    atomic_write_csv(items, out_runs, hdr, float_format="%.5g")
    atomic_write_csv(summary, out_summary, hdr, float_format="%.4g")
    print(summary.drop(columns=["moved_onto_items"]).to_string(index=False))
    return summary


def reruns_attribution(config: Mapping, model_name: str, out_runs, out_summary) -> pd.DataFrame:
    """Chapter 5 rerun with one input changed at a time (``reruns.attribution.variants``): per variant and data
    set one Algorithm 4 run (it draws nothing at random, so one run is its whole distribution), each printed cell
    beside it, and per variant the items the change moves onto the thesis's value."""
    from neckstrength.config import build_directions

    variants = _variants(config, config["reruns"]["attribution"])

    def run(cfg):
        c = cfg["chapter5"]
        model = model_from_config(full_model_from_config(cfg), cfg, model_name)
        d = build_directions(cfg)
        runs = []
        for ds in c["datasets"]:
            data = dataset_from_config(cfg, "chapter5", model, d, ds)
            stream, _ = member_stream(cfg["seed"], "chapter5", model_name, ds, 0)
            m = algorithm4_member(model, data, abc_settings(cfg, model_name), c["bootstrap_direction"],
                                  generator(stream))
            m.insert(0, "member", 0)
            m.insert(0, "dataset", ds)
            m.insert(0, "model", model_name)
            runs.append(m)
        return pd.concat(runs, ignore_index=True)

    frames, failed = _attribution_runs(config, variants, ("chapter5", "data", "geometry", "model", "models", "seed"),
                                       run)
    return _write_attribution(
        config, variants, frames, failed, thesis_with_text(config["data"]["thesis_dir"], model_name), out_runs,
        out_summary,
        f"Chapter 5 ({CHAPTER_TABLES['chapter5'][model_name]}, {model_name}) rerun with one input changed at a time "
        "(reruns.attribution.variants); Algorithm 4 draws nothing at random, so one run per variant and data set "
        "is its whole distribution")


def reruns_attribution_chapter6(config: Mapping, model_name: str, out_runs, out_summary) -> pd.DataFrame:
    """Table 6.1 rerun with one input changed at a time (``reruns.attribution.chapter6``): per variant and data set
    K members of Table 6.1's posterior (``members``; its candidates are drawn at random, so each variant gets its
    own distribution), each printed cell beside their band, and per variant the items the change moves onto the
    thesis's value."""
    from neckstrength.config import build_directions

    a6 = config["reruns"]["attribution"]["chapter6"]
    variants = _variants(config, a6)
    K = int(a6["members"])
    n_cand = config["reruns"]["chapter6"].get("n_candidates")

    def run(cfg):
        model = model_from_config(full_model_from_config(cfg), cfg, model_name)
        d = build_directions(cfg)
        settings = chapter6_settings(cfg, model_name, **({} if n_cand is None else {"n_candidates": int(n_cand)}))
        runs = []
        for ds in a6["datasets"]:
            data = chapter6_dataset(model, d, ds, cfg)
            for k in range(K):
                stream, _ = member_stream(cfg["seed"], "chapter6", model_name, ds, k)
                m = sequential_member(model, data, settings, stream)
                m.insert(0, "member", k)
                m.insert(0, "dataset", ds)
                m.insert(0, "model", model_name)
                runs.append(m)
        return pd.concat(runs, ignore_index=True)

    frames, failed = _attribution_runs(
        config, variants, ("chapter5", "chapter6", "data", "geometry", "model", "models", "seed"), run)
    return _write_attribution(
        config, variants, frames, failed,
        thesis_with_text(config["data"]["thesis_dir"], model_name, config["chapter6"]["thesis_table"]), out_runs,
        out_summary,
        f"Table 6.1 ({model_name}) rerun with one input changed at a time (reruns.attribution.chapter6.variants); "
        f"K = {K} members per variant and data set (the same random streams in every variant: member 0 = the "
        "pipeline's own run)")
