"""Pipeline stage of the clinician-loop study (issue 18 item 4), one function per rule (workflow/rules/clinician.smk)."""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Mapping

import pandas as pd

from neckstrength.config import (
    chapter6_settings,
    deficit_definition,
    derive_rng,
    full_model_from_config,
    head_from_config,
    joint_settings,
    model_from_config,
    plain,
    session_defaults,
)
from neckstrength.estimation.datasets import model_directions_table
from neckstrength.io import atomic_write_csv
from neckstrength.pipeline.common import load_directions


def study_settings_for(config: Mapping, model_name: str):
    """(DeficitDefinition, StudySettings, JointSettings, SequentialSettings) of ``clinician`` for ``model_name``:
    the joint sampler of the clinician session (``clinician.session.<model>``), the study sizes
    (``clinician.study``, per-model overrides in ``clinician.study.model_settings``)."""
    from neckstrength.sequential.deficit import StudySettings

    c = config["clinician"]
    st = dict(c["study"])
    st.update(st.pop("model_settings", {}).get(model_name, {}))
    sess = session_defaults(config, model_name)
    joint = joint_settings(config, **({"n_candidates": int(sess["n_candidates"])} if "n_candidates" in sess else {}))
    thesis = chapter6_settings(config, model_name, n_candidates=int(st.pop("thesis_n_candidates")))
    emg_groups = tuple(config["chapter6"].get("emg_groups", {}).get(model_name, []))
    study = StudySettings(n_deficit=int(st["n_deficit"]), n_normal=int(st["n_normal"]),
                          deficit_range=tuple(map(float, st["deficit_range"])),
                          normal_range=tuple(map(float, st["normal_range"])), noise=float(st["noise"]),
                          n_max=int(st["n_max"]), p_alarm=float(st["p_alarm"]),
                          strategies=tuple(st["strategies"]), n_random=int(st["n_random"]),
                          emg_groups=emg_groups if any("emg" in x for x in st["strategies"]) else (),
                          emg_band=float(st["emg_band"]),
                          **({"surface_azimuth_step_deg": float(st["surface"]["azimuth_step_deg"]),
                              "surface_elevation_deg": tuple(float(x) for x in st["surface"]["elevation_deg"])}
                             if "surface" in st else {}))
    return deficit_definition(config), study, joint, thesis


def surface_directions(model, head, study):
    """(names, U, force scale) of the head-surface points of strategy 'joint_eig+surface': the grid of
    :func:`neckstrength.gap.discriminate.surface_points` (azimuth step and elevations of ``study``, the face left out,
    force along the outward normal); planar models keep the sagittal points."""
    from neckstrength.gap.discriminate import DiscriminateSettings, surface_points
    from neckstrength.model.geometry import direction_table

    pts = surface_points(head, DiscriminateSettings(azimuth_step_deg=study.surface_azimuth_step_deg,
                                                    elevation_deg=tuple(study.surface_elevation_deg)))
    d, U = model_directions_table(model, direction_table(pts, head))
    return list(d["name"]), U, d["force_scale"].to_numpy(float)


def _lean_repr(obj) -> str:
    """``repr`` of a settings dataclass without the fields at their defaults (recursively), so a field added to a
    settings class later, at a default that keeps the old behaviour, leaves the caches of earlier runs valid."""
    from dataclasses import MISSING, fields, is_dataclass

    if not is_dataclass(obj) or isinstance(obj, type):
        return repr(obj)
    parts = []
    for f in fields(obj):
        v = getattr(obj, f.name)
        d = f.default if f.default is not MISSING else (f.default_factory() if f.default_factory is not MISSING
                                                        else MISSING)
        try:
            same = d is not MISSING and type(v) is type(d) and bool(v == d)
        except (TypeError, ValueError):           # arrays and the like: compared by their repr
            same = False
        if not same:
            parts.append(f"{f.name}={_lean_repr(v)}")
    return f"{type(obj).__name__}({', '.join(parts)})"


def _signature(definition, study, joint, thesis, seed: int, model_name: str) -> str:
    return hashlib.sha256(json.dumps(plain({"def": _lean_repr(definition), "study": _lean_repr(study),
                                            "joint": _lean_repr(joint), "thesis": _lean_repr(thesis), "seed": seed,
                                            "model": model_name}),
                                     sort_keys=True).encode()).hexdigest()[:16]


def _read_partials(out_runs, sig: str) -> pd.DataFrame:
    """Rows of every finished participant in ``<out_runs>.partial*.csv`` written with signature ``sig`` (files
    with another signature are removed: their settings are gone)."""
    out = []
    for f in sorted(Path(out_runs).parent.glob(Path(out_runs).name + ".partial*.csv")):
        with f.open() as fh:
            head = fh.readline().strip()
        if head != f"# signature {sig}":
            f.unlink()
            continue
        out.append(pd.read_csv(f, comment="#"))
    return pd.concat(out, ignore_index=True) if out else pd.DataFrame()


def clinician_deficit(config: Mapping, model_name: str, directions_csv, out_runs, out_summary, out_fig,
                      participants=None, interim_dir=None, n_threads: int = 1) -> pd.DataFrame | None:
    """Simulated participants with the deficit group at 25-50% of normal and normal ones: tests until
    P(deficit) > p_alarm for each strategy, false alarms.

    Each finished participant is appended to ``<out_runs>.partial.csv`` with a signature of the settings; a rerun
    (and a run in another process) skips the participants found in any ``<out_runs>.partial*.csv`` with the same
    signature. ``participants`` (indices) runs only those, into ``<out_runs>.partial.<first>-<last>.csv``, and
    writes no outputs: a long run split over processes; the rule's own run then collects them. ``interim_dir``
    runs nothing: the participants finished so far are summarised into that folder (headers say INTERIM, with
    the counts), the partial files stay for the run to resume. ``n_threads``: the solver's threads (same numbers)."""
    from neckstrength.sequential.deficit import detection_summary, run_deficit_study
    from neckstrength.sequential.plots import fig_deficit_study

    model = model_from_config(full_model_from_config(config), config, model_name)
    d, U = model_directions_table(model, load_directions(directions_csv))
    definition, study, joint, thesis = study_settings_for(config, model_name)
    seed = int(config["seed"])
    f0 = model.strengths                                    # the session's prior mean (a = 1)
    sig = _signature(definition, study, joint, thesis, seed, model_name)
    chunk = participants is not None
    if chunk:
        participants = sorted(int(i) for i in participants)
        partial = Path(f"{out_runs}.partial.{participants[0]}-{participants[-1]}.csv")
    else:
        partial = Path(str(out_runs) + ".partial.csv")
    done = _read_partials(out_runs, sig)
    if not done.empty:
        print(f"resuming: {done['participant'].nunique()} participants done", flush=True)
    print(f"clinician study of {model_name}: {definition}\n{study}\njoint {joint}\nthesis N_F {thesis.n_candidates}, "
          f"N_S {thesis.n_sim}\nseed {seed}; streams 'clinician/{model_name}/<what>' + participant index", flush=True)

    def rng_for(what, i):
        return derive_rng(seed, f"clinician/{model_name}/{what}", i)

    interim = interim_dir is not None
    runs_path = out_runs                                    # the partial files live beside the rule's output
    if interim:
        Path(interim_dir).mkdir(parents=True, exist_ok=True)
        out_runs, out_summary, out_fig = (Path(interim_dir) / Path(x).name for x in (out_runs, out_summary, out_fig))

    def done_elsewhere(i: int) -> bool:
        now = _read_partials(runs_path, sig)
        return not now.empty and i in set(now["participant"])

    t0 = time.time()

    def save(one: pd.DataFrame) -> None:
        new = not partial.exists()
        with partial.open("a") as fh:
            if new:
                fh.write(f"# signature {sig}\n")
            one.to_csv(fh, header=new, index=False, float_format="%.6g")

    surface = None
    if "joint_eig+surface" in study.strategies:
        surface = surface_directions(model, head_from_config(config), study)
        print(f"strategy joint_eig+surface: {len(surface[0])} head-surface directions besides the {len(d)} tests",
              flush=True)
    if not interim:
        run_deficit_study(model, list(d["name"]), U, d["force_scale"].to_numpy(float), f0, definition, study,
                          joint, thesis, rng_for, progress=lambda s: print(s, flush=True), on_participant=save,
                          participants=participants, skip=done_elsewhere, n_threads=n_threads, surface=surface)
    if chunk:
        return None
    df = _read_partials(runs_path, sig).drop_duplicates(["participant", "run", "t"])
    df = df.sort_values("participant", kind="stable").reset_index(drop=True)
    per, summ = detection_summary(df, study.p_alarm)
    hdr = [f"clinician loop on {model_name} (issue 18 item 4): P({definition.label()}) on the joint posterior after "
           f"every test; {study.n_deficit} participants with the group at {study.deficit_range[0]:.0%}-"
           f"{study.deficit_range[1]:.0%} of baseline, {study.n_normal} at {study.normal_range[0]:.0%}-"
           f"{study.normal_range[1]:.0%} (other muscles from the prior); forces with log-normal noise sd {study.noise}",
           f"joint posterior: {joint.n_candidates} candidates, kernel noise_rel {joint.noise_rel}, {joint.n_moves} MH "
           f"moves, up to {joint.max_resamples} tempering steps; thesis criterion: Eq. 6.7 on its own scheme "
           f"(N_F {thesis.n_candidates}, N_S {thesis.n_sim}), order replayed on the joint posterior; seed {seed}",
           f"P(deficit) is checked here only on data simulated from the fitted model (well-specified); "
           f"alarm = P(deficit) > {study.p_alarm}",
           ("INTERIM: " if interim else "") + f"participants included: "
           f"{df.loc[df['kind'] == 'deficit', 'participant'].nunique()} deficit, "
           f"{df.loc[df['kind'] == 'normal', 'participant'].nunique()} normal"]
    atomic_write_csv(df, out_runs, hdr, float_format="%.6g")
    atomic_write_csv(summ, out_summary, hdr + ["t_detect_*: tests until the alarm among deficit participants "
                                               "(runs without an alarm count as beyond t_max: inf); "
                                               "false_alarm_rate: share of normal participants' runs with an alarm "
                                               "at any t"], float_format="%.4g")
    atomic_write_csv(per, Path(out_runs).with_name("deficit_per_run.csv"), hdr, float_format="%.6g")
    fig_deficit_study(df, per, study.p_alarm, out_fig,
                      f"P({definition.label()}) on s3m24-simulated participants ({model_name}; "
                      f"{per.loc[per['kind'] == 'deficit', 'participant'].nunique()} deficit, "
                      f"{per.loc[per['kind'] == 'normal', 'participant'].nunique()} normal; N {joint.n_candidates})"
                      + (" INTERIM" if interim else ""))
    print(summ.to_string(index=False), flush=True)
    print(f"done in {time.time() - t0:.0f} s", flush=True)
    if not interim:
        for f in Path(runs_path).parent.glob(Path(runs_path).name + ".partial*.csv"):
            f.unlink()
    return summ


def _protocol_signature(decision, study, joint, seed: int, model_name: str, protocol: str, extra) -> str:
    """What one protocol's runs depend on: the decision, the joint sampler, the cohort, the number of tests, the
    seed, the model, and the protocol's own settings (EMG groups and band; postures; Algorithm 4's settings and
    tests). The checkpoints, false-alarm rate and the other protocols do not enter: adding a protocol or
    changing a read-out reruns nothing."""
    from dataclasses import replace

    own = {"forces+emg": ("emg_groups", "emg_band"), "forces+emg+deep": ("emg_groups", "emg_band"),
           "forces+postures": ("postures",), "alg4": ("alg4_tests", "bootstrap_direction")}.get(protocol, ())
    keep = {k: getattr(study, k) for k in own}
    core = replace(study, protocols=(), checkpoints=(), false_alarm=0.05, misfit_level=0.05,
                   emg_groups=(), emg_band=0.05, postures=("neutral",), alg4_tests=(25,), bootstrap_direction="",
                   patients_per_kind=())
    return _signature(decision, core, joint, {"protocol": protocol, **{k: repr(v) for k, v in keep.items()},
                                              "extra": repr(extra)}, seed, model_name)


def _aside(path: Path, sig: str) -> Path:
    """Where a protocol's cache written with signature ``sig`` is kept while another signature is in use."""
    import hashlib

    return path.with_name(f"{path.stem}.{hashlib.sha256(sig.encode()).hexdigest()[:12]}{path.suffix}")


def _signature_of(path: Path) -> str:
    with path.open() as fh:
        head = fh.readline().strip()
    return head[len("# signature "):] if head.startswith("# signature ") else ""


def _read_cache(path: Path, sig: str) -> pd.DataFrame:
    """The rows of a protocol's cache file written with signature ``sig``. A file with another signature is set
    aside (``<name>.<hash of its signature>.csv``, not deleted: its runs took hours), and one set aside earlier
    with ``sig`` is taken back, so returning to earlier settings reuses their runs."""
    if path.exists():
        old = _signature_of(path)
        if old == sig:
            return pd.read_csv(path, comment="#")
        path.replace(_aside(path, old))
    back = _aside(path, sig)
    if back.exists() and _signature_of(back) == sig:
        back.replace(path)
        return pd.read_csv(path, comment="#")
    return pd.DataFrame()


def _append_cache(path: Path, sig: str, rows: pd.DataFrame) -> None:
    """Append one (participant, protocol) run to a protocol's cache, in the columns of the file's header (a column
    the rows lack is left empty, one the header lacks is dropped: rows written by an earlier version still read)."""
    new = not path.exists()
    if not new:
        with path.open() as fh:
            fh.readline()
            cols = fh.readline().strip().split(",")
        rows = rows.reindex(columns=cols)
    with path.open("a") as fh:
        if new:
            fh.write(f"# signature {sig}\n")
        rows.to_csv(fh, header=new, index=False, float_format="%.8g")


def clinician_decision(config: Mapping, model_name: str, directions_csv, out_runs, out_roc, out_sequential,
                       out_reliability, out_fig, n_threads: int = 1) -> pd.DataFrame:
    """The deficit decision measured on simulated patients (issue 31 item 4): ROC, the stopping rule, reliability,
    the recalibration of P(deficit) and the calibrated misfit guard (from the forces-only runs).

    (participant, protocol) runs go to ``n_threads`` forked processes; each finished one is appended to its
    protocol's cache, ``decision_cache/<protocol>.csv`` beside ``out_runs``, headed by a signature of what that
    protocol's runs depend on (:func:`_protocol_signature`), so an interrupted run resumes where it stopped and a
    protocol added later (or a changed read-out) reruns only what depends on the change. The cache stays after
    the outputs are written."""
    from dataclasses import replace

    from neckstrength.config import abc_settings, decision_settings, decision_study_settings
    from neckstrength.gap.forked import fork_map
    from neckstrength.sequential.decision_plots import fig_decision_study
    from neckstrength.sequential.decision_study import fit_misfit_guard, misfit_flag_table, recalibrate, \
        reliability_table, roc_table, rule_grid, run_decision_study, sequential_table

    model = model_from_config(full_model_from_config(config), config, model_name)
    d, U = model_directions_table(model, load_directions(directions_csv))
    study, n_cand = decision_study_settings(config, model_name)
    # the study measures the model's own Bayes factor and the heuristic guard: no recalibration and no calibrated
    # guard (both are made here, from these runs)
    decision = decision_settings(config, n_candidates=n_cand, calibration=None, misfit_guard=None)
    joint = joint_settings(config)
    seed = int(config["seed"])
    f0 = model.strengths
    abc = abc_settings(config, model_name) if "alg4" in study.protocols else None
    force_length = config.get("postures", {}).get("force_length", "relative")
    cache_dir = Path(out_runs).parent / "decision_cache"
    cache_dir.mkdir(parents=True, exist_ok=True)
    sigs = {p: _protocol_signature(decision, study, joint, seed, model_name, p,
                                   abc if p == "alg4" else (force_length if p == "forces+postures" else None))
            for p in study.protocols}
    caches = {p: cache_dir / f"{p}.csv" for p in study.protocols}
    n = study.cohort.n_deficit + study.cohort.n_normal
    done = {p: _read_cache(caches[p], sigs[p]) for p in study.protocols}
    finished = {p: set() if df.empty else set(df["participant"]) for p, df in done.items()}
    # alg4 after fewer tests than directions reads the forces protocol's order: forces first
    order = sorted(study.protocols, key=lambda p: (p != "forces", p == "alg4"))
    todo = [(p, i) for p in order for i in study.participants(p) if i not in finished[p]]
    print(f"decision study of {model_name}: {decision.label()}\n{decision}\n{study}\nseed {seed}; streams "
          f"'decision/{model_name}/<truth|candidates>' + participant index; done before: "
          + ", ".join(f"{p} {len(finished[p] & set(study.participants(p)))} of {len(study.participants(p))}"
                      for p in order), flush=True)

    def rng_for(what, i):
        return derive_rng(seed, f"decision/{model_name}/{what}", i)

    dirs, fs = list(d["name"]), d["force_scale"].to_numpy(float)

    pset = None
    if "forces+postures" in study.protocols:
        from neckstrength.postures.model import build_posture_set
        from neckstrength.postures.tables import load_posture_tables

        pset = build_posture_set(full_model_from_config(config), model,
                                 load_posture_tables(config["data"]["model_dir"], list(study.postures)),
                                 list(study.postures), force_length)

    def alg4_order(i):
        f = _read_cache(caches["forces"], sigs["forces"]) if "forces" in caches else pd.DataFrame()
        g = f[(f["participant"] == i) & (f["t"] >= 1)].sort_values("t") if not f.empty else f
        if g.empty:
            raise ValueError(f"alg4 after fewer than {len(dirs)} tests needs the forces protocol's order "
                             f"(participant {i} has no forces run)")
        return list(g["direction"])

    def one(job):
        protocol, i = job
        return run_decision_study(model, dirs, U, fs, f0, decision, joint, replace(study, protocols=(protocol,)),
                                  rng_for, participants=[i], progress=lambda s: print(s, flush=True), pset=pset,
                                  abc=abc, alg4_order=alg4_order)

    t0 = time.time()
    # forces before alg4 (alg4 may read its order): the other protocols first, alg4 after every forces run is in
    first = [j for j in todo if j[0] != "alg4"]
    for batch in (first, [j for j in todo if j[0] == "alg4"]):
        for k, rows in fork_map(one, batch, max(1, int(n_threads))):
            _append_cache(caches[batch[k][0]], sigs[batch[k][0]], rows)
    runs = pd.concat([_read_cache(caches[p], sigs[p]) for p in study.protocols], ignore_index=True)
    runs = runs.drop_duplicates(["participant", "protocol", "t"])
    keep = {p: set(study.participants(p)) for p in study.protocols}      # a cache may hold more (an earlier k)
    runs = runs[[i in keep[p] for p, i in zip(runs["protocol"], runs["participant"])]]
    runs = runs.sort_values(["participant", "protocol", "t"], kind="stable").reset_index(drop=True)
    cps = tuple(t for t in study.checkpoints if t <= study.n_max)
    roc = roc_table(runs, cps, study.false_alarm, decision.p_decide)
    per, seq = sequential_table(runs, decision.p_decide, decision.min_tests)
    grid = rule_grid(runs)
    rel = reliability_table(runs, cps)
    hdr = [f"deficit decision on {model_name} (issue 31): {decision.label()}; per hypothesis {decision.n_candidates} "
           f"candidates, resample-move below ESS {decision.resample_ess}, {decision.n_moves} MH moves; seed {seed}",
           f"simulated patients (truths apart from the priors, neckstrength.sequential.cohort): "
           f"{study.cohort.n_deficit} with each side of {'+'.join(decision.group)} at "
           f"{study.cohort.deficit_range[0]:.0%}-{study.cohort.deficit_range[1]:.0%}, {study.cohort.n_normal} normal "
           f"(>= {study.cohort.normal_floor:.0%}); groups log-sd {study.cohort.group_log_sd}, sides "
           f"{study.cohort.side_log_sd}; force noise {study.cohort.noise}; tests in decision_eig order"]
    atomic_write_csv(runs, out_runs, hdr, float_format="%.6g")
    atomic_write_csv(roc, out_roc, hdr + [f"auc: ROC area of log BF (Hanley-McNeil se); sensitivity_at_fa: best "
                                          f"sensitivity at false alarms <= {study.false_alarm} with the threshold "
                                          f"chosen on these normals (optimistic); rule_*: P(deficit) >= "
                                          f"{decision.p_decide} after t tests (Wilson 95% intervals)"],
                     float_format="%.4g")
    atomic_write_csv(seq, out_sequential, hdr + [f"the stopping rule: decided at the first test from the "
                                                 f"{decision.min_tests}th with P >= {decision.p_decide} or <= "
                                                 f"{1 - decision.p_decide:.2g}"],
                     float_format="%.4g")
    atomic_write_csv(per, Path(out_sequential).with_name("decision_per_run.csv"), hdr, float_format="%.6g")
    atomic_write_csv(grid, Path(out_sequential).with_name("decision_rule_grid.csv"),
                     hdr + ["the stopping rule's outcome for other thresholds and minimum numbers of tests (the same "
                            "runs: the test order does not depend on the rule)"], float_format="%.4g")
    atomic_write_csv(rel, out_reliability, hdr + ["reliability of P(deficit) at the cohort's share of deficits "
                                                  f"({study.cohort.n_deficit / n:.0%}; prevalence setting "
                                                  f"{decision.prevalence:.0%}); Jeffreys 95% intervals"],
                     float_format="%.4g")
    if "forces" in study.protocols:
        cal, rel_cal, rule_cal = recalibrate(runs[runs["protocol"] == "forces"], decision, model_name, len(dirs), cps,
                                             false_alarm=study.false_alarm,
                                             source=f"decision study of {model_name}, seed {seed}")
        atomic_write_csv(cal.to_frame(), Path(out_roc).with_name("decision_calibration.csv"),
                         hdr + ["the recalibration of the Bayes factor fitted on these runs (forces only; every t >= "
                                f"{decision.min_tests}); to use it in sessions and estimates, copy this file to "
                                "data/calibration/ and point clinician.decision.calibration at it"],
                         float_format="%.8g")
        atomic_write_csv(pd.concat([rel_cal, rule_cal], ignore_index=True),
                         Path(out_roc).with_name("decision_recalibrated.csv"),
                         hdr + ["held out (2 folds by participant parity, each fold scored with the map fitted on the "
                                "other): reliability of the recalibrated P(deficit) (Jeffreys 95% intervals), and per "
                                f"t the recalibrated rule P >= {decision.p_decide} and a log BF threshold chosen on the "
                                f"other fold's normals for false alarms <= {study.false_alarm} (Wilson 95%)",
                                f"map: {cal}"], float_format="%.4g")
        rel = pd.concat([rel, rel_cal], ignore_index=True)
        print(f"recalibration: {cal.label()}\n{rule_cal.to_string(index=False)}", flush=True)
        guard, gcheck = fit_misfit_guard(runs, decision, model_name, len(dirs), study.misfit_level,
                                         source=f"decision study of {model_name}, seed {seed}")
        flags = misfit_flag_table(runs, guard, decision.min_tests)
        atomic_write_csv(guard.to_frame(), Path(out_roc).with_name("decision_misfit_guard.csv"),
                         hdr + ["the calibrated misfit guard fitted on these runs (forces only): flag when the best "
                                "fit's log RMS exceeds log_median + factor x log_sd of these patients at that t (t = "
                                "t_from, t_from + 1, ...); to use it, copy this file to data/calibration/ and point "
                                "clinician.decision.misfit_guard at it"], float_format="%.8g")
        atomic_write_csv(pd.concat([gcheck.assign(what="held-out false flags on the model's own patients"),
                                    flags.assign(what=f"flagged at level {study.misfit_level:g} (in-sample for "
                                                      "forces)")], ignore_index=True),
                         Path(out_roc).with_name("decision_misfit.csv"),
                         hdr + [f"misfit guard: {guard.label()}", "rows 'held-out': per level, the share of the "
                                "model's own patients flagged at any t >= t_from by the guard fitted on the other "
                                "fold (2 folds by participant); rows 'flagged': per protocol and kind"],
                         float_format="%.4g")
        print(f"misfit guard: {guard.label()}\n{gcheck.to_string(index=False)}\n{flags.to_string(index=False)}",
              flush=True)
    else:
        for name in ("decision_calibration.csv", "decision_recalibrated.csv", "decision_misfit_guard.csv",
                     "decision_misfit.csv"):
            atomic_write_csv(pd.DataFrame({"note": ["no forces-only protocol in this study: nothing recalibrated"]}),
                             Path(out_roc).with_name(name), hdr)
    fig_decision_study(runs, rel, cps, decision.p_decide, out_fig,
                       f"deficit decision on {model_name}-simulated patients: a cohort of {study.cohort.n_deficit} "
                       f"deficit, {study.cohort.n_normal} normal (each protocol's own count in its ROC title); noise "
                       f"{study.cohort.noise:.0%}; seed {seed}")
    print(roc.to_string(index=False), flush=True)
    print(seq.to_string(index=False), flush=True)
    print(f"done in {time.time() - t0:.0f} s", flush=True)
    return roc
