"""Command-line entry point: ``neckstrength <verb> ...``.

Verbs:
  derive-model   derive the full-model tables from an OpenSim .osim (needs the 'opensim' extra)
  directions     write the test-direction table for a config
  max-wrench     maximum wrench of a model in every test direction (baseline or given strengths)
  validate       check a measurement / activation / test-point file and report the first problem
  session        clinician-in-the-loop session: start, resume, replay (docs/session.md)
  app            the clinician's session in a browser and its ask/tell HTTP API (docs/app.md)
  diagnose       sim-to-real gap diagnosis of a data set: where, which effect, how far (docs/gap_diagnosis.md)
  import-trials  a lab's trial table -> max-force / activation tables + quality report (docs/trials.md)
  estimate       strengths of one participant from a table or trials: Algorithm 4, ABC-SMC or joint estimator
  example-lab    write the SYNTHETIC example lab data set (trials generated from the model)
  c3d-to-trials  C3D files (one per trial, listed in a manifest) -> trial table + EMG signals (needs 'c3d' extra)
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from neckstrength.config import load_config
from neckstrength.io import DataValidationError


# --- output folders: nothing of an earlier run or of the inputs is replaced without --force -------------------------

def _same_path(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def _check_out(out, force: bool, inputs=(), files=None) -> Path | None:
    """Check an ``--out`` folder before anything is written; returns the topmost folder this run will create.

    ``files``: the files the command writes there (each must not exist, unless ``force``); None: the command writes a
    varying set, so the folder must be empty (``force``: write into it). An input is never overwritten, even with
    ``force``. Raises :class:`DataValidationError` (one line) otherwise.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise DataValidationError(out, "--out names an existing file; give a folder (new or empty)")
    ins = [Path(i) for i in inputs if i]
    if files is not None:
        for f in map(Path, files):
            for i in ins:
                if _same_path(f, i):
                    raise DataValidationError(f, "is an input of this command and is never overwritten; choose "
                                                 "another --out")
            if f.is_dir():
                raise DataValidationError(f, "is a folder; this command writes a file of that name there")
        existing = [Path(f) for f in files if Path(f).exists()]
        if existing and not force:
            more = f" (and {len(existing) - 1} more output(s))" if len(existing) > 1 else ""
            raise DataValidationError(existing[0], f"exists{more}; give --force to replace it, or choose another "
                                                   "--out")
    elif out.is_dir():
        entries = sorted(out.iterdir())
        if entries and not force:
            raise DataValidationError(out, f"--out folder is not empty ({len(entries)} entries, e.g. "
                                           f"{entries[0].name}); give --force to write into it, or choose another "
                                           "--out")
        for i in ins:
            if entries and i.exists() and out.resolve() in i.resolve().parents:
                raise DataValidationError(i, f"is an input inside --out {out}, which --force could overwrite; "
                                             "choose another --out")
    top = None
    for d in [out, *out.parents]:
        if d.exists():
            break
        top = d
    return top


@contextlib.contextmanager
def _removed_on_failure(created: Path | None):
    """Remove ``created`` (a folder this run made, see :func:`_check_out`) when the block fails; the caller sets
    ``state['ok']`` when it succeeded (a non-zero exit code counts as failure)."""
    state = {"ok": False}
    try:
        yield state
    finally:
        if not state["ok"] and created is not None and created.is_dir():
            shutil.rmtree(created, ignore_errors=True)


def _add_force(d) -> None:
    d.add_argument("--force", action="store_true",
                   help="replace outputs of an earlier run in --out (never an input of this command)")


def _cmd_directions(args) -> int:
    from neckstrength.config import build_directions
    from neckstrength.io import atomic_write_csv
    from neckstrength.model.geometry import DIRECTIONS_HEADER

    atomic_write_csv(build_directions(_config(args.config)), args.out, DIRECTIONS_HEADER)   # full precision
    print(f"wrote {args.out}")
    return 0


def _cmd_max_wrench(args) -> int:
    from neckstrength.config import build_directions, full_model_from_config, model_from_config
    from neckstrength.estimation.datasets import model_directions_table
    from neckstrength.wrench import solve
    from neckstrength.wrench.problem import STATUS_CODES

    cfg = _config(args.config)
    full = full_model_from_config(cfg)
    model = model_from_config(full, cfg, args.model)
    f = model.strengths.copy()
    if args.strengths:
        s = pd.read_csv(args.strengths, comment="#")
        if not {"muscle", "strength_N"} <= set(s.columns):
            raise DataValidationError(args.strengths, "needs columns muscle, strength_N")
        lookup = dict(zip(s["muscle"], s["strength_N"]))
        unknown = set(lookup) - set(model.muscle_names)
        if unknown:
            raise DataValidationError(args.strengths, f"unknown muscles {sorted(unknown)}", field_name="muscle")
        f = np.array([lookup.get(m, fm) for m, fm in zip(model.muscle_names, f)])
    d, U = model_directions_table(model, build_directions(cfg))
    if args.direction:
        keep = d["name"].isin(args.direction).to_numpy()
        if not keep.any():
            raise SystemExit(f"no direction named {args.direction}; known: {', '.join(d['name'])}")
        d, U = d[keep].reset_index(drop=True), U[keep]
    with _stdout_to_stderr():  # HiGHS's start-up banner on stderr, the table on stdout
        w, alpha, status = solve(model, f[None, :], U, method="highs")
    out = pd.DataFrame({"direction": d["name"], "wrench": w[0], "force_N": w[0] / d["force_scale"].to_numpy(),
                        "status": [STATUS_CODES[s] for s in status[0]]})
    print(f"model {model.name}: {model.m} muscles, {model.n} coordinates")
    print(out.to_string(index=False, float_format=lambda x: f"{x:.2f}"))
    return 0


def _cmd_validate(args) -> int:
    from neckstrength.io import read_activations, read_measurements
    from neckstrength.model.geometry import read_test_points

    if args.kind == "trials":
        return _cmd_validate_trials(args)
    if args.kind in ("measurements", "activations"):
        names = _direction_names(args.config)
        reader = {"measurements": read_measurements, "activations": read_activations}[args.kind]
        df = reader(args.file, names)
    else:
        df = read_test_points(args.file)
    print(f"{args.file}: OK ({len(df)} rows, columns: {', '.join(map(str, df.columns))})")
    return 0


def _config(path) -> dict:
    """The config (defaults of every setting); a missing file is an input error, not a traceback."""
    if not Path(path).is_file():
        raise DataValidationError(path, "config file not found: run from the repository root (config/config.yaml) "
                                  "or give --config")
    return load_config(path)


def _direction_names(config_path) -> list[str]:
    from neckstrength.config import build_directions

    return list(build_directions(_config(config_path))["name"])


def _trial_settings(args, cfg):
    """The config's ``trials.settings`` with the command line's options on top."""
    from neckstrength.config import trial_settings

    pad = getattr(args, "pad_offset", None)
    over = {"angle_deg": getattr(args, "angle_deg", None), "ratio_tol": getattr(args, "ratio_tol", None),
            "mismatch_action": getattr(args, "mismatch", None),
            "pad_to_c0_m": None if pad is None else tuple(float(x) for x in pad)}
    return replace(trial_settings(cfg), **{k: v for k, v in over.items() if v is not None})


def _cmd_validate_trials(args) -> int:
    from neckstrength.config import build_directions
    from neckstrength.trials import import_trials

    cfg = _config(args.config)
    res = import_trials(args.file, build_directions(cfg), _trial_settings(args, cfg), args.signals)
    s = res.summary
    print(f"{args.file}: OK ({s['trials']} trials, {s['participants']} participants; {s['matched']} matched, "
          f"{s['kept']} kept, {s['excluded_trials']} not used, {s['missing_directions']} direction(s) without a value; "
          f"run import-trials for the report)")
    return 0


def _cmd_import_trials(args) -> int:
    from neckstrength.config import build_directions
    from neckstrength.trials import import_to_folder

    from neckstrength.trials import default_outputs

    cfg = _config(args.config)
    created = _check_out(args.out, args.force, [args.trials, args.signals, args.config],
                         list(default_outputs(args.out).values()))
    with _removed_on_failure(created) as done:
        res, outputs = import_to_folder(args.trials, build_directions(cfg), args.out, _trial_settings(args, cfg),
                                        args.signals)
        done["ok"] = True
    s = res.summary
    print(f"{s['trials']} trials, {s['participants']} participants ({', '.join(s['participant_ids'])}): "
          f"{s['matched']} matched the target direction, {s['excluded_mismatch']} excluded as not matched, "
          f"{s['kept']} kept (largest valid per direction), {s['missing_directions']} participant x direction "
          f"cell(s) without a value")
    for r in res.fatigue.to_dict("records"):
        print(f"  {r['participant']}: cardinal end vs start {r['mean_change_rel']:+.1%} "
              f"({'FATIGUED' if r['fatigued'] else 'ok'})")
    for m in s["emg_missing"]:
        print(f"  {m['participant']}: EMG channel {m['channel']} not recorded")
    print(f"wrote {outputs['max_force']}, {outputs['activation']}, {outputs['report']} (+ exclusions, figure)")
    return 0


def _cmd_example_lab(args) -> int:
    from neckstrength.trials.synthetic import write_example

    cfg = _config(args.config)
    created = _check_out(args.out, args.force, [args.config],
                         [Path(args.out) / "trials.csv", Path(args.out) / "true_strengths.csv"])
    with _removed_on_failure(created) as done:
        paths = write_example(cfg, args.out, args.seed)
        done["ok"] = True
    print(f"wrote SYNTHETIC {paths['trials']} and {paths['truth']} (seed {args.seed})")
    return 0


def _cmd_estimate(args) -> int:
    cfg = _config(args.config)
    out = Path(args.out)
    measurements, activations = args.measurements, args.activations
    if measurements is None and not args.trials:
        print("error: give --measurements (a Table A.2-layout file) or --trials", file=sys.stderr)
        return 2
    created = _check_out(out, args.force, [measurements, activations, args.trials, args.signals, args.config])
    with _removed_on_failure(created) as done:
        rc = _estimate_into(args, cfg, out, measurements, activations)
        done["ok"] = rc == 0
    return rc


def _estimate_into(args, cfg, out: Path, measurements, activations) -> int:
    from neckstrength.estimate import run_estimate

    if args.trials:
        from neckstrength.config import build_directions
        from neckstrength.trials import import_to_folder

        with contextlib.redirect_stdout(sys.stderr):
            _, outputs = import_to_folder(args.trials, build_directions(cfg), out / "import",
                                          _trial_settings(args, cfg), args.signals)
        measurements, activations = outputs["max_force"], activations or outputs["activation"]
        print(f"imported trials -> {outputs['max_force']} (quality report {outputs['report']})", file=sys.stderr)
    if measurements is None:
        print("error: give --measurements (a Table A.2-layout file) or --trials", file=sys.stderr)
        return 2
    from neckstrength.config import build_directions, estimate_settings, full_model_from_config, model_from_config

    settings = estimate_settings(cfg, args.model).with_options(seed=args.seed, emg=args.emg, max_iter=args.max_iter,
                                                               criterion=args.criterion)
    model = model_from_config(full_model_from_config(cfg), cfg, args.model)
    with contextlib.redirect_stdout(sys.stderr):
        s = run_estimate(settings, model, build_directions(cfg), args.participant, measurements, out, args.method,
                         activations, args.threads, log=lambda m: print(m, file=sys.stderr, flush=True),
                         figures=not args.no_figures)
    head = f"{args.method} estimate, model {args.model}, participant {args.participant}, seed {s['seed']}"
    if "iterations" in s:
        head += f": {s['iterations']} iterations, converged {s['converged']}, D(f_c) = {s['D_fc']:.3f}"
    print(head)
    if s["directions_dropped"]:
        print(f"directions without a value (not used): {', '.join(s['directions_dropped'])}")
    print(s["table"].to_string(index=False, float_format=lambda x: f"{x:.4g}"))
    if "sigma_c" in s["table"].columns:
        print("sigma_c: Algorithm 4's sampling width, a heuristic - NOT a calibrated uncertainty (its f_c(1 +- sigma_c) "
              "covered 22% of 700 true p2m7 strengths in simulation; docs/calibration.md)")
    figs = args.method != "joint" and not args.no_figures
    print(f"results{' and figures' if figs else ''} in {out}/ (run.json records the inputs and the seed)")
    return 0


def _cmd_c3d(args) -> int:
    cfg = _config(args.config)
    channels = {}
    for item in args.channel or []:
        if "=" not in item:
            print(f"error: --channel {item!r}: expected NAME=LABEL (e.g. Fx=Force.Fx1)", file=sys.stderr)
            return 2
        k, v = item.split("=", 1)
        channels[k.strip()] = v.strip()
    s = _trial_settings(args, cfg)
    out = Path(args.out)
    created = _check_out(out, args.force, [args.manifest, args.config], [out / "trials.csv", out / "signals.csv"])
    with _removed_on_failure(created) as done:
        _c3d_write(args, cfg, channels, s, out)
        done["ok"] = True
    print(f"wrote {out / 'trials.csv'} and {out / 'signals.csv'}; next: neckstrength "
          f"import-trials {out / 'trials.csv'} --signals {out / 'signals.csv'} --out <folder>")
    return 0


def _c3d_write(args, cfg, channels, s, out: Path) -> None:
    from neckstrength.config import build_directions
    from neckstrength.io import atomic_write_csv
    from neckstrength.trials import default_frames
    from neckstrength.trials.c3d import c3d_to_tables

    trials, signals = c3d_to_tables(args.manifest, build_directions(cfg), channels,
                                    default_frames(s.pad_to_c0_m, s.frames))
    atomic_write_csv(trials, out / "trials.csv", [f"from C3D files listed in {args.manifest}",
                                                   "units: Mx=N*m; My=N*m; Mz=N*m; Fx=N; Fy=N; Fz=N; peak_time_s=s"],
                     float_format="%.6g")
    atomic_write_csv(signals, out / "signals.csv", [f"EMG analog channels from C3D files listed in {args.manifest}",
                                                     "units: time_s=s"], float_format="%.6g")
    print(f"{len(trials)} trials from {args.manifest}")


def _cmd_derive(args) -> int:
    from neckstrength.model.opensim import derive as derive_opensim

    argv = ["--osim", args.osim, "--out", args.out]
    if args.multifidus_osim:
        argv += ["--multifidus-osim", args.multifidus_osim]
    rc = derive_opensim.main(argv) or 0
    if rc == 0 and args.postures:
        from neckstrength.model.opensim import postures as derive_postures

        if not args.multifidus_osim:
            raise SystemExit("derive-model --postures needs --multifidus-osim")
        rc = derive_postures.main(["--osim", args.osim, "--multifidus-osim", args.multifidus_osim,
                                   "--out", str(Path(args.out) / "postures")]) or 0
    return rc


def _cmd_session(args) -> int:
    from neckstrength.session import InputError, Session, SessionOptions, parse_priorities, replay_into, run_interactive

    try:
        if args.action == "resume":
            s = Session.resume(args.out, progress=print, threads=args.threads)
            return run_interactive(s)
        opts = SessionOptions(model=args.model, participant=args.participant,
                              priorities=parse_priorities(args.priority), config=args.config,
                              n_candidates=args.n_candidates, prior_scale=args.prior_scale,
                              gain_frac=args.stop_frac, cache=args.cache, seed=args.seed, criterion=args.criterion,
                              postures=args.postures, posture_change_cost=args.posture_change_cost,
                              prevalence=args.prevalence, noise=args.noise, noise_source=args.noise_source,
                              emg_channels=args.emg)
        if args.action == "replay":          # a failed replay removes what it created (session.json, log, lock)
            return replay_into(args.out, opts, args.csv, threads=args.threads)
        return run_interactive(Session.create(args.out, opts, progress=print, threads=args.threads))
    except (InputError, ValueError, FileExistsError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _cmd_app(args) -> int:
    from neckstrength.app import serve

    return serve(root=args.root, config=args.config, host=args.host, port=args.port, token=args.token,
                 open_browser=not args.no_browser, threads=args.threads, cache=args.cache)


def _cmd_diagnose(args) -> int:
    from neckstrength.gap.stage import DATASET_FILES, FIGURES

    from neckstrength.config import gap_measurements_path, gap_models

    cfg = _config(args.config)
    model = args.model or gap_models(cfg)[0]
    out = Path(args.out or f"results/gap/{model}/{args.dataset}")
    outputs = {k: out / f"{k}.csv" for k in DATASET_FILES}
    outputs.update({f"fig_{k}": out / f"fig_{k}.png" for k in FIGURES})
    outputs.update({"summary": out / "summary.json", "report": out / "report.md"})
    if args.extra_trials:
        outputs["update"] = out / "update.csv"
    created = _check_out(out, args.force, [args.config, args.measurements, args.extra_trials,
                                           args.measurements or gap_measurements_path(cfg)])
    with _removed_on_failure(created) as done:
        rc = _diagnose_into(args, cfg, model, out, outputs)
        done["ok"] = rc == 0
    return rc


@contextlib.contextmanager
def _stdout_to_stderr():
    """Send file descriptor 1 to standard error for the block: HiGHS prints its start-up banner from C on the
    process's standard output, where only the command's answer belongs."""
    sys.stdout.flush()
    try:
        fd = sys.__stdout__.fileno()
        saved = os.dup(fd)
    except (AttributeError, OSError, ValueError):  # no real stdout (embedded): nothing to redirect
        yield
        return
    try:
        os.dup2(sys.__stderr__.fileno(), fd)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, fd)
        os.close(saved)


def _diagnose_into(args, cfg, model, out, outputs) -> int:
    from neckstrength.config import build_directions, diagnose_stage
    from neckstrength.gap.stage import answer_lines, header_line, run_diagnose, write_diagnose

    effects = tuple(e.strip() for e in (args.effects or "").split(",") if e.strip())
    try:
        with _stdout_to_stderr():  # progress and HiGHS's banner on stderr, the answer on stdout
            settings, inputs = diagnose_stage(cfg, model, args.dataset, build_directions(cfg),
                                              measurements=args.measurements, extra_trials=args.extra_trials,
                                              effects=effects, workers=args.workers)
            result = run_diagnose(settings, inputs, resume_dir=out / "resume")
            write_diagnose(result, outputs)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    s = result.summary
    print(header_line(inputs))
    for line in answer_lines(result):
        print(line)
    which = s.get("named", s["chosen"])
    if s.get("decided_by") == "evidence":
        which = f"{which} (Bayes evidence; calibrated test: {s.get('named_calibrated', s['chosen'])})"
    print(f"wrote {out}/report.md: where {s['worst_plane']} / {s['worst_component']}; which {which}; "
          f"held-out gap {s['gap_before']:.3f} -> {s['gap_after']:.3f}")
    return 0


# One line of description and an example per subcommand (shown by `neckstrength <command> --help`).
COMMANDS = {
    "derive-model": ("Derive the full-model tables (strengths, moment arms, optionally the posture tables) from an "
                     "OpenSim neck model. Needs the 'opensim' extra; the default pipeline never does.",
                     "neckstrength derive-model --osim Mortensen2014_rigidTorso.osim "
                     "--multifidus-osim ModelOfNeckAndShoulder.osim --out data/model"),
    "directions": ("Write the table of the test directions of a config (points, normals, unit wrenches, planes) at "
                   "full precision.",
                   "neckstrength directions --config config/config.yaml --out results/geometry/directions.csv"),
    "max-wrench": ("Maximum wrench and force of a model in each test direction (the max-wrench LP, solved by HiGHS), "
                   "for the baseline strengths or the strengths of a CSV.",
                   "neckstrength max-wrench --model s3m24 --direction back"),
    "validate": ("Check an input file (measurements, activations, test points or a trial table) against the config "
                 "and report the first problem with its file, row and field. Writes nothing.",
                 "neckstrength validate measurements data/thesis/table_A2_max_force.csv"),
    "session": ("Clinician-in-the-loop session: propose the next test, take the measured force, update the "
                "estimate, recommend when to stop (docs/session.md).",
                "neckstrength session start --model p2m7 --participant P01 --out sessions/P01"),
    "session start": ("Start an interactive session in a new folder; every accepted entry is logged before the "
                      "estimate changes.",
                      "neckstrength session start --model s3m24 --participant P01 --out sessions/P01"),
    "session replay": ("Run a session non-interactively from a CSV of measurements (direction,force_N"
                       "[,activations]); gives the same numbers as the interactive session.",
                       "neckstrength session replay --csv measurements.csv --out sessions/P01-replay"),
    "session resume": ("Continue a session from its log (session.log.jsonl) in the same state, e.g. after a crash.",
                       "neckstrength session resume --out sessions/P01"),
    "app": ("The clinician's session in a browser (start, test, live estimate, summary, export) and its ask/tell "
            "HTTP API, on this machine only; prints the URL with its access token (docs/app.md).",
            "neckstrength app --root sessions"),
    "diagnose": ("Sim-to-real gap diagnosis of one data set of maximum forces: where the model misses, which "
                 "unmodelled effect explains it (named only with a calibrated p-value), how far the held-out gap "
                 "shrinks (docs/gap_diagnosis.md).",
                 "neckstrength diagnose --measurements max_force.csv --dataset P01 --model p2m7 --out results/P01_gap"),
    "import-trials": ("Import a lab's trial table: match each trial to its test direction, keep the largest valid "
                      "trial per direction, check fatigue and EMG; writes max_force.csv, activation.csv and "
                      "quality_report.md (docs/trials.md).",
                      "neckstrength import-trials data/example_lab/trials.csv --out results/example_lab/import"),
    "estimate": ("Estimate one participant's muscle strengths from a max-force table or a trial table: Algorithm 4 "
                 "(Chapter 5), Algorithm 4 then ABC-SMC, or the joint estimator (Chapter 6), with the pipeline's "
                 "settings.",
                 "neckstrength estimate --measurements max_force.csv --participant P01 --model p2m7 "
                 "--out results/P01_p2m7"),
    "c3d-to-trials": ("Convert C3D files (one per trial, listed in a manifest) into a trial table and an EMG signals "
                      "table for import-trials. Needs the 'c3d' extra.",
                      "neckstrength c3d-to-trials manifest.csv --out results/lab_c3d"),
    "example-lab": ("Write the SYNTHETIC example lab data set (trials generated from the s3m24 model, with direction "
                    "errors, noise, fatigue and a missing EMG channel) and its true strengths.",
                    "neckstrength example-lab --out data/example_lab --seed 20261123"),
}


def _doc(command: str) -> dict:
    """add_parser keywords: the command's description and example."""
    description, example = COMMANDS[command]
    return {"description": textwrap.fill(description, 100), "epilog": f"example:\n  {example}",
            "formatter_class": argparse.RawDescriptionHelpFormatter}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("neckstrength")
    except PackageNotFoundError:                     # running from a source tree that is not installed
        from neckstrength import __version__

        return __version__


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="neckstrength", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="`neckstrength <command> --help` describes a command and gives an example.")
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="verb", required=True)

    d = sub.add_parser("derive-model", **_doc("derive-model"),
                       help="derive full-model tables from an OpenSim model (needs opensim)")
    d.add_argument("--osim", required=True, help="the OpenSim neck model (.osim) to derive the 96 muscles from")
    d.add_argument("--multifidus-osim", default=None,
                   help="a second .osim that supplies the multifidus (needed for --postures)")
    d.add_argument("--out", default="data/model", help="output folder of the model tables (default data/model)")
    d.add_argument("--postures", action="store_true",
                   help="also derive the posture tables into <out>/postures (docs/postures.md)")
    d.set_defaults(func=_cmd_derive)

    d = sub.add_parser("directions", **_doc("directions"), help="write the test-direction table")
    d.add_argument("--config", default="config/config.yaml", help="config whose geometry section defines the "
                                                                   "directions (default config/config.yaml)")
    d.add_argument("--out", default="results/geometry/directions.csv", help="output CSV")
    d.set_defaults(func=_cmd_directions)

    d = sub.add_parser("max-wrench", **_doc("max-wrench"), help="max wrench of a model in the test directions")
    d.add_argument("--config", default="config/config.yaml",
                   help="settings and test directions (default config/config.yaml)")
    d.add_argument("--model", default="s3m24", help="p2m7, p3m12, s3m24 or <kinematic>-<grouping>")
    d.add_argument("--strengths", default=None, help="CSV with columns muscle,strength_N (others: baseline)")
    d.add_argument("--direction", action="append", help="restrict to this direction (repeatable)")
    d.set_defaults(func=_cmd_max_wrench)

    d = sub.add_parser("validate", **_doc("validate"), help="validate an input file")
    d.add_argument("kind", choices=["measurements", "activations", "points", "trials"],
                   help="measurements (Table A.2 layout), activations (Table A.3), points (test-point coordinates) "
                        "or trials (a lab's trial table, docs/trials.md)")
    d.add_argument("file", help="the file to check")
    d.add_argument("--config", default="config/config.yaml", help="test directions (names) come from this config")
    d.add_argument("--signals", default=None, help="trials: EMG signals file (docs/trials.md)")
    d.set_defaults(func=_cmd_validate)

    d = sub.add_parser("session", **_doc("session"),
                       help="clinician-in-the-loop session (propose, measure, update, stop)")
    ss = d.add_subparsers(dest="action", required=True)
    for action in ("start", "replay"):
        a = ss.add_parser(action, **_doc(f"session {action}"),
                          help="start an interactive session" if action == "start" else
                          "run a session from a CSV of measurements (direction,force_N[,activations])")
        if action == "replay":
            a.add_argument("--csv", required=True, help="measurements: direction,force_N[,activations] per row")
        a.add_argument("--out", required=True, help="session folder (log, summary)")
        a.add_argument("--model", default="p2m7", choices=["p2m7", "p3m12", "s3m24"], help="model (default p2m7)")
        a.add_argument("--participant", default="anonymous", help="participant name written to the session files")
        a.add_argument("--priority", action="append", metavar="MUSCLE=WEIGHT",
                       help="Eq. 6.8 muscle priority (repeatable; unlisted muscles weigh 0)")
        a.add_argument("--config", default="config/config.yaml",
                       help="settings and test directions (default config/config.yaml)")
        a.add_argument("--n-candidates", type=int, default=None, help="N_F (default: config chapter6)")
        a.add_argument("--prior-scale", type=float, default=1.0, help="a in the prior f_0 = a f'_base")
        a.add_argument("--stop-frac", type=float, default=None,
                       help="stop when the best expected reduction < this share of the first step's "
                            "(default: config chapter6.stop.gain_frac)")
        a.add_argument("--cache", default=None, help="candidate-set cache folder (default results/session_cache)")
        a.add_argument("--seed", type=int, default=None, help="default: config seed")
        a.add_argument("--criterion", default=None, choices=["joint_eig", "marginal_entropy", "thesis"],
                       help="next-test criterion: joint_eig or marginal_entropy on the joint posterior, or thesis "
                            "(Algorithms 7-9 on per-muscle PDFs); default: config clinician.session.<model> "
                            "(s3m24: joint_eig), else thesis")
        a.add_argument("--postures", default=None, metavar="P1,P2,...|all",
                       help="tests in these neck postures as well as neutral (config postures.postures; 'all' = every "
                            "one): the joint posterior proposes a (posture, direction) test; default: neutral only "
                            "(docs/session.md)")
        a.add_argument("--posture-change-cost", type=float, default=0.0, metavar="NATS",
                       help="with --postures: nats charged by the criterion for a test in another posture than the "
                            "last one (default 0)")
        a.add_argument("--prevalence", type=float, default=None,
                       help="prior probability of a deep-extensor deficit for this patient (the deficit decision; "
                            "default: config clinician.decision.prevalence, 0.5)")
        a.add_argument("--noise", type=float, default=None, metavar="SD",
                       help="measurement noise of the forces as the sd of the relative error, e.g. from this lab's "
                            "repeat trials (default: config clinician.decision.noise, 0.05)")
        a.add_argument("--noise-source", default=None,
                       help="where --noise comes from, printed with the decision (e.g. 'repeats of P01, 3 trials')")
        a.add_argument("--emg", default=None, metavar="CH1,CH2,...|surface|deep|all",
                       help="the EMG channels recorded (muscles; surface: config chapter6.emg_groups, deep: the "
                            "deficit group, fine-wire): act= accepts only these; default: not chosen, any muscle")
    a = ss.add_parser("resume", **_doc("session resume"), help="resume a session from its log")
    a.add_argument("--out", required=True, help="the session folder to resume")
    for a in ss.choices.values():
        a.add_argument("--threads", type=int, default=0,
                       help="threads of the joint posterior's solver (directions solved concurrently; the numbers do "
                            "not depend on it); default 0 = every core")
    d.set_defaults(func=_cmd_session)

    d = sub.add_parser("app", **_doc("app"), help="the session in a browser, and its ask/tell HTTP API")
    d.add_argument("--root", default="sessions", help="folder of the session folders (default sessions)")
    d.add_argument("--config", default="config/config.yaml",
                   help="settings and test directions of new sessions (default config/config.yaml)")
    d.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default 127.0.0.1: this machine only; another address is reachable from "
                        "the network, protected by the token alone)")
    d.add_argument("--port", type=int, default=0, help="port (default 0: a free port)")
    d.add_argument("--token", default=None, help="access token (default: a new random one, printed)")
    d.add_argument("--no-browser", action="store_true", help="do not open a browser (print the URL only)")
    d.add_argument("--cache", default=None, help="candidate-set cache folder (default results/session_cache)")
    d.add_argument("--threads", type=int, default=0,
                   help="threads of the joint posterior's solver (the numbers do not depend on it); 0 = every core")
    d.set_defaults(func=_cmd_app)

    d = sub.add_parser("diagnose", **_doc("diagnose"), help="sim-to-real gap diagnosis of one data set (forces only)")
    d.add_argument("--config", default="config/config.yaml",
                   help="settings and test directions (default config/config.yaml)")
    d.add_argument("--model", default=None, help="p2m7, p3m12, s3m24 or <kinematic>-<grouping> (default: "
                                                 "first of config gap.models)")
    d.add_argument("--dataset", "--participant", dest="dataset", required=True,
                   help="participant column of the measurement table, or norm/weak")
    d.add_argument("--measurements", default=None, help="a measurement table in the Table A.2 layout "
                                                        "(default: config gap.measurements / data.measurements)")
    d.add_argument("--effects", default=None, help="comma-separated effects (default: config gap.effects)")
    d.add_argument("--out", default=None, help="output folder (default results/gap/<model>/<dataset>)")
    _add_force(d)
    d.add_argument("--workers", "--threads", dest="workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="processes for the effects' grids and the calibration's screen (default 2, as the "
                        "pipeline rule; each may need about 1 GB more; the answer does not depend on it)")
    d.add_argument("--extra-trials", default=None,
                   help="CSV of additional trials (columns measurement, force_N; e.g. the proposed ones of "
                        "discrimination.csv, measured): posterior of the top candidates given them (update.csv)")
    d.set_defaults(func=_cmd_diagnose)

    def trial_options(a):
        a.add_argument("--signals", default=None, help="EMG signals file: raw EMG per sample (docs/trials.md)")
        a.add_argument("--angle-deg", type=float, default=None, help="direction window, deg (default 20)")
        a.add_argument("--ratio-tol", type=float, default=None, help="R_fm window (default 0.10)")
        a.add_argument("--mismatch", choices=["drop", "flag"], default=None,
                       help="trials outside the window: drop (default) or keep flagged")
        a.add_argument("--pad-offset", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                       help="C0-C1 relative to the lower posterior pad centre, m (default 0.08 -0.02 0)")

    d = sub.add_parser("import-trials", **_doc("import-trials"),
                       help="trial table -> max-force and activation tables + quality report")
    d.add_argument("trials", help="trial table (CSV, docs/trials.md)")
    d.add_argument("--out", required=True, help="output folder")
    _add_force(d)
    d.add_argument("--config", default="config/config.yaml",
                   help="settings and test directions (default config/config.yaml)")
    trial_options(d)
    d.set_defaults(func=_cmd_import_trials)

    d = sub.add_parser("estimate", **_doc("estimate"),
                       help="estimate one participant's strengths from a table or trials")
    src = d.add_mutually_exclusive_group(required=True)
    src.add_argument("--measurements", default=None, help="max-force table, Table A.2 layout")
    src.add_argument("--trials", default=None, help="trial table: imported first into <out>/import")
    d.add_argument("--participant", required=True, help="participant column (e.g. S003, P01)")
    d.add_argument("--activations", default=None, help="activation table, Table A.3 layout (for --emg a3_band)")
    d.add_argument("--model", default="p2m7", help="p2m7, p3m12, s3m24 or <kinematic>-<grouping>")
    d.add_argument("--method", choices=["alg4", "smc", "joint"], default="alg4",
                   help="alg4: Algorithm 4 (Ch. 5); smc: Algorithm 4 then ABC-SMC; joint: joint estimator (Ch. 6)")
    d.add_argument("--out", required=True, help="output folder (results, figures, run.json)")
    _add_force(d)
    d.add_argument("--config", default="config/config.yaml", help="defaults of every setting (not edited)")
    d.add_argument("--seed", type=int, default=None, help="default: the config's seed (recorded in run.json)")
    d.add_argument("--emg", choices=["none", "a3_band"], default="none", help="EMG bounds (as chapter5.participant_emg)")
    d.add_argument("--max-iter", type=int, default=None, help="Algorithm 4 iterations cap (default: config)")
    d.add_argument("--threads", type=int, default=1,
                   help="threads of the max-wrench solver (default 1)")
    d.add_argument("--criterion", default="joint_eig", choices=["joint_eig", "marginal_entropy"],
                   help="joint: test-selection criterion")
    d.add_argument("--no-figures", action="store_true", help="skip the figures (Algorithm 4 / ABC-SMC)")
    trial_options(d)
    d.set_defaults(func=_cmd_estimate)

    d = sub.add_parser("c3d-to-trials", **_doc("c3d-to-trials"),
                       help="C3D files of a manifest -> trial table + EMG signals (c3d extra)")
    d.add_argument("manifest", help="CSV: path,participant,direction,block,trial,frame (one C3D file per trial)")
    d.add_argument("--out", required=True, help="output folder (trials.csv, signals.csv)")
    _add_force(d)
    d.add_argument("--config", default="config/config.yaml", help="test directions of this config")
    d.add_argument("--channel", action="append", metavar="NAME=LABEL",
                   help="analog label of Fx..Mz or an EMG channel (SCM_R, ...) when it differs (repeatable)")
    d.set_defaults(func=_cmd_c3d)

    d = sub.add_parser("example-lab", **_doc("example-lab"), help="write the SYNTHETIC example lab data set")
    d.add_argument("--out", default="data/example_lab", help="output folder (default data/example_lab)")
    _add_force(d)
    d.add_argument("--config", default="config/config.yaml", help="model and test directions of this config")
    d.add_argument("--seed", type=int, default=20261123, help="seed of the synthetic trials (default 20261123)")
    d.set_defaults(func=_cmd_example_lab)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except DataValidationError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
