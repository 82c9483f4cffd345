"""Run records for the report: run time and peak memory per job, software versions and seeds.

Run time and memory come from two records the run keeps anyway, so no rule needs a ``benchmark:`` directive:

- **Snakemake's metadata** (``.snakemake/metadata/``, one JSON record per output file): rule, log files and the
  job's ``starttime``/``endtime`` as Snakemake recorded them. ``seconds`` = endtime - starttime (wall clock,
  including interpreter start-up and imports).
- **A job record** appended to the job's log by :func:`install_job_record` when a rule script exits: peak resident
  memory of the script process (:func:`peak_rss_mb`: ``VmHWM`` on Linux), CPU seconds (``getrusage``), the
  wildcards, threads and declared ``mem_mb``. ``neckstrength/__init__.py`` installs it, and only inside a Snakemake
  script job (a ``snakemake`` object in ``__main__``); every rule script imports the package, so every job is
  covered without touching the scripts.

Jobs that ran before the record existed (or whose log lost it) get ``peak_rss_mb`` = NaN; jobs without metadata
fall back to the record's own wall time (``time_source`` says which).
"""

from __future__ import annotations

import atexit
import json
import os
import platform
import sys
import time
from base64 import urlsafe_b64decode
from pathlib import Path
from typing import Iterable, Mapping

import pandas as pd

from neckstrength.seeds import STREAMS, describe

RECORD_MARKER = "# neckstrength job record: "


SOFTWARE = ("python", "numpy", "scipy", "pandas", "highspy", "statsmodels", "pingouin", "matplotlib", "snakemake",
            "neckstrength")


_T0 = time.time()


def _rss_mb(ru_maxrss: float) -> float:
    # Linux reports kilobytes, macOS bytes
    return ru_maxrss / (1024 * 1024) if sys.platform == "darwin" else ru_maxrss / 1024


def _process_start() -> float:
    """Start time of this process (epoch seconds) from /proc; the package import time elsewhere."""
    try:
        stat = Path("/proc/self/stat").read_text()
        ticks = int(stat.rsplit(")", 1)[1].split()[19])
        btime = next(int(line.split()[1]) for line in Path("/proc/stat").read_text().splitlines()
                     if line.startswith("btime"))
        return btime + ticks / os.sysconf("SC_CLK_TCK")
    except Exception:  # noqa: BLE001 - not Linux
        return _T0


def peak_rss_mb() -> float:
    """Peak resident memory of this process (MB).

    Linux: ``VmHWM`` of /proc/self/status, the high-water mark of this process image only. (``ru_maxrss`` is not
    used there: the kernel carries it over from the pre-exec image, i.e. from the Snakemake process that spawned
    the job, so every job would report at least Snakemake's own size.) Elsewhere: ``ru_maxrss``.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    import resource

    return _rss_mb(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def job_record(rule: str, wildcards: Mapping, threads, mem_mb, start: float) -> dict:
    import resource

    me = resource.getrusage(resource.RUSAGE_SELF)
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    end = time.time()
    return {"rule": rule, "wildcards": ",".join(f"{k}={v}" for k, v in wildcards.items()), "threads": threads,
            "mem_mb_declared": mem_mb, "wall_s": round(end - start, 3),
            "cpu_s": round(me.ru_utime + me.ru_stime + ch.ru_utime + ch.ru_stime, 3),
            "peak_rss_mb": round(peak_rss_mb(), 1),
            # children (none in the current rules): ru_maxrss, an upper bound (see peak_rss_mb)
            "peak_rss_children_mb": round(_rss_mb(ch.ru_maxrss), 1),
            "start": start, "end": end, "host": platform.node(), "pid": os.getpid()}


def _append_record(log: str, rule: str, wildcards: dict, threads, mem_mb, start: float) -> None:
    try:
        rec = job_record(rule, wildcards, threads, mem_mb, start)
        with open(log, "a", encoding="utf-8") as fh:
            fh.write("\n" + RECORD_MARKER + json.dumps(rec) + "\n")
    except Exception:  # noqa: BLE001 - a failed record must never fail the job
        pass


def install_job_record() -> bool:
    """Inside a Snakemake script job, append a job record to the job's first log file when the process exits."""
    main = sys.modules.get("__main__")
    smk = getattr(main, "snakemake", None)
    if smk is None or getattr(main, "_neckstrength_job_record", False):
        return False
    try:
        log = str(list(smk.log)[0])
        rule = str(smk.rule)
        wildcards = {k: str(v) for k, v in smk.wildcards.items()}
        threads = int(smk.threads)
        mem_mb = smk.resources.get("mem_mb") if hasattr(smk.resources, "get") else None
    except Exception:  # noqa: BLE001 - not a script job with a log
        return False
    main._neckstrength_job_record = True
    atexit.register(_append_record, log, rule, wildcards, threads, mem_mb, _process_start())
    return True


def read_job_record(log: str | Path) -> dict | None:
    """The last job record in a log file, or None."""
    try:
        lines = Path(log).read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        if line.startswith(RECORD_MARKER):
            try:
                return json.loads(line[len(RECORD_MARKER):])
            except json.JSONDecodeError:
                return None
    return None


def _decode_record_path(rel: Path) -> str:
    parts = [p[1:] if p.startswith("@") else p for p in rel.parts]
    return urlsafe_b64decode("".join(parts).encode()).decode()


def snakemake_metadata(metadata_dir: str | Path = ".snakemake/metadata") -> list[dict]:
    """Snakemake's per-output metadata records (file persistence backend), each with its output path."""
    root = Path(metadata_dir)
    out = []
    if not root.is_dir():
        return out
    for f in root.rglob("*"):
        if not f.is_file():
            continue
        try:
            rec = json.loads(f.read_text())
            rec["output"] = _decode_record_path(f.relative_to(root))
        except (ValueError, OSError, UnicodeDecodeError):
            continue
        if isinstance(rec, dict) and rec.get("rule"):
            out.append(rec)
    return out


def runtime_table(metadata_dir: str | Path = ".snakemake/metadata", logs: Iterable[str] | None = None,
                  exclude_rules: Iterable[str] = ()) -> pd.DataFrame:
    """One row per job: rule, wildcards, seconds, peak RSS (MB), CPU seconds, declared threads / mem_mb.

    Jobs are identified by their log file (every rule has one). Only records whose output still exists count
    (the latest execution of each job). ``logs`` adds log files without metadata (their record's wall time is
    used).
    """
    exclude = set(exclude_rules)
    jobs: dict[tuple, dict] = {}
    for rec in snakemake_metadata(metadata_dir):
        if rec.get("incomplete") or rec["rule"] in exclude or not os.path.exists(rec["output"]):
            continue
        log = tuple(rec.get("log") or ())
        key = (rec["rule"], log or (rec["output"],))
        j = jobs.setdefault(key, {"rule": rec["rule"], "log": log[0] if log else "", "outputs": [],
                                  "starttime": rec.get("starttime"), "endtime": rec.get("endtime")})
        j["outputs"].append(rec["output"])
        if rec.get("starttime") is not None:
            j["starttime"] = min(x for x in (j["starttime"], rec["starttime"]) if x is not None)
        if rec.get("endtime") is not None:
            j["endtime"] = max(x for x in (j["endtime"], rec["endtime"]) if x is not None)
    known_logs = {j["log"] for j in jobs.values()}
    for log in logs or ():
        if log not in known_logs:
            rec = read_job_record(log)
            if rec and rec.get("rule") not in exclude:
                jobs[(rec["rule"], (log,))] = {"rule": rec["rule"], "log": log, "outputs": [], "starttime": None,
                                               "endtime": None}
    rows = []
    for j in jobs.values():
        rec = read_job_record(j["log"]) if j["log"] else None
        if j["starttime"] is not None and j["endtime"] is not None:
            seconds, source = j["endtime"] - j["starttime"], "snakemake metadata"
            start = j["starttime"]
        elif rec:
            seconds, source, start = rec["wall_s"], "job record", rec.get("start")
        else:
            seconds, source, start = float("nan"), "none", None
        rows.append({"rule": j["rule"], "wildcards": rec["wildcards"] if rec else "",
                     "seconds": round(float(seconds), 2),
                     "peak_rss_mb": rec["peak_rss_mb"] if rec else float("nan"),
                     "peak_rss_children_mb": rec.get("peak_rss_children_mb", float("nan")) if rec else float("nan"),
                     "cpu_seconds": rec["cpu_s"] if rec else float("nan"),
                     "threads": rec.get("threads") if rec else None,
                     "mem_mb_declared": rec.get("mem_mb_declared") if rec else None,
                     "started": pd.Timestamp(start, unit="s").isoformat(timespec="seconds") if start else "",
                     "time_source": source, "memory_source": "job record" if rec else "none",
                     "log": j["log"], "n_outputs": len(j["outputs"])})
    cols = ["rule", "wildcards", "seconds", "peak_rss_mb", "peak_rss_children_mb", "cpu_seconds", "threads",
            "mem_mb_declared", "started", "time_source", "memory_source", "log", "n_outputs"]
    df = pd.DataFrame(rows, columns=cols)
    return df.sort_values(["started", "rule", "wildcards"]).reset_index(drop=True)


def runtime_by_rule(jobs: pd.DataFrame) -> pd.DataFrame:
    """Per rule: number of jobs, total / max seconds, max peak RSS and the declared mem_mb."""
    if jobs.empty:
        return pd.DataFrame(columns=["rule", "jobs", "total_seconds", "max_seconds", "max_peak_rss_mb",
                                     "mem_mb_declared"])
    g = jobs.groupby("rule", sort=False)
    out = pd.DataFrame({"jobs": g.size(), "total_seconds": g["seconds"].sum().round(1),
                        "max_seconds": g["seconds"].max().round(1),
                        "max_peak_rss_mb": g["peak_rss_mb"].max().round(0),
                        "mem_mb_declared": g["mem_mb_declared"].max()}).reset_index()
    return out.sort_values("total_seconds", ascending=False).reset_index(drop=True)


def software_versions(packages: Iterable[str] = SOFTWARE) -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for p in packages:
        if p == "python":
            out[p] = platform.python_version()
            continue
        try:
            out[p] = version(p)
        except PackageNotFoundError:
            out[p] = "not installed"
    return out


def seed_rows(seed: int | None, chapter3_synthetic: bool = True,
              chapter5_runs: Iterable[tuple[str, str]] = ()) -> list[dict]:
    """Every seed the pipeline uses, derived from config 'seed' exactly as the stages derive them
    (:mod:`neckstrength.seeds`): the seed, the Chapter 3 cohort's stream (``chapter3_synthetic``: the cohort is drawn,
    config ``chapter3.data`` unset), the Chapter 5 runs' streams (``chapter5_runs``: (model, data set) pairs), then
    one row per registered stream key (:data:`neckstrength.seeds.STREAMS`)."""
    rows = [{"kind": "seed", "name": "seed", "value": str(seed),
             "note": "config 'seed': recorded in every table header"}]

    if chapter3_synthetic:
        rows.append({"kind": "seed", "name": "chapter3 SYNTHETIC cohort",
                     "value": describe(seed, "chapter3/synthetic"),
                     "note": "stream 'chapter3/synthetic' (neckstrength.pipeline.chapter3.chapter3_synthetic_cohort)"})
    for m, d in chapter5_runs:
        rows.append({"kind": "seed", "name": f"chapter5 {m}/{d}", "value": describe(seed, f"{m}/{d}"),
                     "note": "stream 'model/dataset' (neckstrength.pipeline.chapter5.chapter5_estimate)"})
    for st in STREAMS:
        rows.append({"kind": "stream", "name": " | ".join(repr(k) for k in st.keys),
                     "value": ("SeedSequence(seed)" if st.root else "SeedSequence([seed, crc32(key)"
                               + (f", {st.extra}" if st.extra else "") + "])"),
                     "note": f"{st.what} ({st.by})"})
    return rows


def environment_table(seed: int | None, chapter3_synthetic: bool = True,
                      chapter5_runs: Iterable[tuple[str, str]] = ()) -> pd.DataFrame:
    """Software versions, platform and every seed (:func:`seed_rows`)."""
    rows = [{"kind": "software", "name": k, "value": v, "note": ""} for k, v in software_versions().items()]
    rows += [{"kind": "platform", "name": "system", "value": f"{platform.system()} {platform.release()}",
              "note": platform.machine()},
             {"kind": "platform", "name": "cpus", "value": str(os.cpu_count()), "note": "visible to the job"}]
    rows += seed_rows(seed, chapter3_synthetic, chapter5_runs)
    return pd.DataFrame(rows, columns=["kind", "name", "value", "note"])
