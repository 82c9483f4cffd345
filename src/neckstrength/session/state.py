"""The clinician session's engine: :class:`Session` (state, decision, estimate, proposals) and its options
=======================================================================================================

One session = one participant, one model, one folder (``session.json``, ``session.log.jsonl``, outputs). The engine
returns data and text and never reads input or prints (progress goes to the ``progress`` callback, silent unless
given); the terminal (:mod:`neckstrength.session.repl`) and any other front end drive it through the same calls,
so identical entries give identical numbers:

- :meth:`Session.create` (alias :meth:`Session.start`) / :meth:`Session.resume`   open a session folder;
- :meth:`Session.propose`   the proposed test and every alternative with its expected information (a dict);
- :meth:`Session.tell`      an :class:`~neckstrength.session.parse.Entry` or a prompt line -> the acknowledged
  record, written and fsync'd to the log before the estimate changes and before it returns;
- :meth:`Session.undo`, :meth:`Session.stop`   the same for undo and stop (stop writes the summary files);
- :meth:`Session.snapshot`  everything a screen shows, as a plain JSON-serialisable dict;
- :meth:`Session.result`    the session's result so far in memory (:class:`~neckstrength.session.stage.SessionResult`),
  which :func:`~neckstrength.session.stage.write_session` writes (a stop does).

As a stage (issue 33): the settings (:class:`~neckstrength.session.settings.SessionSettings`) and inputs (the model,
its directions, where to push, the posture models: :class:`~neckstrength.session.stage.SessionInputs`) are built once
by :func:`neckstrength.config.session_stage` when a session is created or resumed; the engine reads no config and no
model file. Its posterior is :class:`~neckstrength.sequential.joint.JointPosterior` (through
:class:`~neckstrength.sequential.joint_state.JointState`, which adds undo), the engine of ``neckstrength estimate
--method joint`` too, and its decision :class:`~neckstrength.sequential.decision.DeficitDecision`, the decision
study's.

Choices the thesis does not make (docs/session.md): the prior is ``N(a f'_base, (0.3 a f'_base)^2)`` with ``a`` a
session option (default 1) because Sec. 6.5.1's ``a`` needs every measurement up front; the stop recommendation
is the prospective criterion of :func:`~neckstrength.sequential.stop_by_expected_gain` (best Eq. 6.7/6.8 score
below ``gain_frac`` of the first step's; config ``chapter6.stop.gain_frac``); the proposals are deterministic per
set of tested directions (seeded from the session seed and the tested set), so undo, resume and replay give the same
numbers.
"""

from __future__ import annotations

import difflib
import functools
import json
import math
import os
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from neckstrength.errors import InputError
from neckstrength.postures.model import pair_label, split_label
from neckstrength.seeds import derive_rng, generator, seed_sequence
from neckstrength.sequential.algorithms import (
    Proposal,
    SequentialState,
    SimulatedSet,
    StrengthGrid,
    pdf_entropy,
    sample_prior,
    sim_key,
)
from neckstrength.session import render
from neckstrength.session.log import HEADER, LOG, SessionLog, effective_entries
from neckstrength.session.parse import Entry, _check_direction, parse_entry
from neckstrength.session.settings import SessionSettings, resolve_postures  # noqa: F401  (re-exported)
from neckstrength.session.stage import SessionInputs, SessionResult, write_session

MODELS = ("p2m7", "s3m24", "p3m12")


# next-test criteria: on the joint posterior (joint_eig, marginal_entropy) or the thesis's scheme (Algorithms 7-9)
CRITERIA = ("joint_eig", "marginal_entropy", "thesis")


@dataclass
class SessionOptions:
    """Everything that fixes a session's numbers (written to ``session.json``)."""

    model: str = "p2m7"
    participant: str = "anonymous"
    priorities: dict = field(default_factory=dict)     # Eq. 6.8 gamma {muscle: weight}; empty = Eq. 6.7
    config: str = "config/config.yaml"
    n_candidates: int | None = None                     # None = config chapter6.n_candidates (per model)
    prior_scale: float = 1.0                            # a in f_0 = a f'_base
    gain_frac: float | None = None                      # None = config chapter6.stop.gain_frac
    cache: str | None = None                            # candidate-set cache folder
    seed: int | None = None                             # None = config seed
    criterion: str | None = None                        # joint_eig / marginal_entropy (joint posterior) or thesis
                                                        # (Algorithms 7-9); None = config clinician.session.<model>
    postures: list | str | None = None                  # tests in these postures (issue 20; 'all' = config
                                                        # postures.postures); None = neutral only (the thesis's tests)
    posture_change_cost: float = 0.0                    # nats charged per posture change by the criterion
    prevalence: float | None = None                     # prior P(deficit) of the decision; None = config
                                                        # clinician.decision.prevalence
    noise: float | None = None                          # the decision's measurement noise (sd of the relative
                                                        # force error); None = config clinician.decision.noise
    noise_source: str | None = None                     # where ``noise`` comes from (printed with the answer)
    emg_channels: list | str | None = None              # the muscles whose EMG is recorded (:func:`emg_choices`;
                                                        # 'surface', 'deep', 'all' or names); None = not chosen: any
                                                        # muscle's activation is accepted (the terminal's act=)


def session_threads(threads: int | None) -> int:
    """Threads of the joint posterior's solver calls (directions solved concurrently; the numbers are the same for
    any count). None or 0: every core of this machine (``os.cpu_count()``), as an interactive session has the
    machine to itself; the step times of docs/clinician.md were measured with 2 threads on 2 cores."""
    if threads is None or int(threads) == 0:
        return max(1, os.cpu_count() or 1)
    if int(threads) < 0:
        raise ValueError(f"--threads: {threads!r} must be >= 0 (0 = every core)")
    return int(threads)


def emg_choices(muscles: Sequence[str], surface_groups: Sequence[str], deep: Sequence[int]) -> dict:
    """The EMG channels a session of a model with these ``muscles`` offers: ``{"surface": [...], "deep": [...]}``.
    Surface: the muscles of ``surface_groups`` (config chapter6.emg_groups.<model>: the surface EMG of Appendix A.1,
    both sides), the channels the decision study's ``forces+emg`` protocol simulates; deep: the deficit decision's
    group (``deep``: its muscle indices; fine-wire EMG, the study's ``forces+emg+deep``). A channel bounds the
    muscle's activation to the value entered +- the joint posterior's ``emg_band``."""
    base = [m[:-2] if m.endswith(("-R", "-L")) else m for m in muscles]
    deep_names = [muscles[i] for i in sorted(int(i) for i in deep)]
    surface = [m for m, b in zip(muscles, base) if b in set(surface_groups) and m not in deep_names]
    return {"surface": surface, "deep": deep_names}


def resolve_emg_channels(spec: str | Sequence[str] | None, choices: dict) -> list[str] | None:
    """``--emg`` -> the session's EMG channels in the model's muscle order (None: not chosen). ``spec``: a
    comma-separated string or a list of channel names, or ``surface``, ``deep``, ``all`` (= both); an empty list or
    ``none``: no EMG recorded (every act= is refused)."""
    if spec is None:
        return None
    items = [x.strip() for x in (spec.split(",") if isinstance(spec, str) else spec)]
    items = [x for x in items if x]
    allowed = list(choices["surface"]) + list(choices["deep"])
    if items in ([], ["none"]):
        return []
    want: set[str] = set()
    for x in items:
        if not isinstance(x, str):
            raise ValueError(f"--emg: channel {x!r} is not a name; allowed: {', '.join(allowed) or 'none'}")
        if x in ("surface", "deep", "all"):
            want |= set(allowed if x == "all" else choices[x])
            continue
        if x not in allowed:
            close = difflib.get_close_matches(x, allowed, n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise ValueError(f"--emg: '{x}' is not an EMG channel of this model{hint}; allowed: "
                             f"{', '.join(allowed) or 'none'} (or surface, deep, all)")
        want.add(x)
    return [m for m in allowed if m in want]


def _silent(_: str) -> None:
    pass


def _one_blas_thread(fn):
    """Run ``fn`` with numpy's BLAS on one thread (:func:`~neckstrength.wrench.batched.single_threaded_blas`): the
    engine's products are small (candidates x muscles), and a multi-threaded BLAS spends more time synchronising
    than computing, worst on a busy machine (the resample-move steps took twice as long, benchmarks/bench_app.py).
    The parallelism is the solver threads'. The numbers are the same (each product is computed the same way)."""
    @functools.wraps(fn)
    def run(self, *args, **kw):
        if not self.one_blas_thread:
            return fn(self, *args, **kw)
        from neckstrength.wrench.batched import single_threaded_blas

        with single_threaded_blas():
            return fn(self, *args, **kw)
    return run


class Session:
    """One participant's session in folder ``out`` (header, log, outputs).

    Open one with :meth:`create` (a new folder) or :meth:`resume` (an existing one), not with the constructor
    (which writes no header; it takes the ``settings`` and ``inputs`` that :func:`neckstrength.config.session_stage`
    builds from ``opts``, and reads nothing else). ``progress``: a callback for what the engine is doing while it builds the candidates
    (silent when None); ``threads``: the joint posterior's solver threads (the numbers do not depend on it).
    """

    #: numpy's BLAS on one thread inside the engine's calls, and the deficit decision updated beside the joint
    #: posterior (in its worker process, or a second thread) (False: the decision after the joint posterior in this
    #: process, the reference of benchmarks/bench_app.py; the numbers are the same either way)
    one_blas_thread = True
    concurrent_decision = True
    #: with ``concurrent_decision``: the decision in a worker process of its own (session/worker.py) rather than a
    #: thread, so the two do not share Python's interpreter lock (False: a thread; the numbers are the same)
    decision_process = True

    def __init__(self, out: str | Path, opts: SessionOptions, settings: SessionSettings, inputs: SessionInputs,
                 progress: Callable[[str], None] | None = None, threads: int | None = None):
        self.out = Path(out)
        self.progress = progress = progress or _silent
        self.threads = session_threads(threads)     # not in the header: the numbers do not depend on it
        self.config_settings = cs = settings
        postures = inputs.postures
        cost = float(opts.posture_change_cost)
        if not np.isfinite(cost) or cost < 0:
            raise ValueError(f"--posture-change-cost: {opts.posture_change_cost!r} must be >= 0 (nats)")
        if cost > 0 and postures is None:
            raise ValueError("--posture-change-cost needs --postures (a session in neutral only never changes posture)")
        crit = opts.criterion or cs.criterion
        if crit not in CRITERIA:
            raise ValueError(f"unknown criterion {crit!r}; known: {', '.join(CRITERIA)}")
        if postures is not None and crit == "thesis":
            if opts.criterion == "thesis":
                raise ValueError("--postures needs the joint posterior (--criterion joint_eig or marginal_entropy): "
                                 "the thesis's scheme (Algorithms 7-9) has no posture model")
            crit = "joint_eig"
        if opts.n_candidates is None and crit != "thesis" and cs.n_candidates is not None:
            opts = replace(opts, n_candidates=cs.n_candidates)
        # resolved: the header fixes the session's numbers
        self.opts = opts = replace(opts, criterion=crit, postures=postures, posture_change_cost=cost)
        self.postures = postures
        self.criterion = crit
        self.joint = crit != "thesis"
        self.deficit = cs.deficit
        self.model = inputs.model
        self.muscles = list(self.model.muscle_names)
        unknown = set(opts.priorities) - set(self.muscles)
        if unknown:
            raise ValueError(f"priorities for unknown muscles {sorted(unknown)}; muscles of {opts.model}: "
                             f"{', '.join(self.muscles)}")
        over = {} if opts.n_candidates is None else {"n_candidates": int(opts.n_candidates)}
        if self.joint and opts.priorities and crit == "joint_eig":
            raise ValueError("muscle priorities (Eq. 6.8) need --criterion marginal_entropy or thesis; joint_eig "
                             "scores the information about all muscles together")
        self.settings = replace(cs.joint if self.joint else cs.sequential, **over)
        d, U = inputs.directions, inputs.U
        self.U = U
        self.dirtable = d
        self.directions = list(d["name"])
        self.base_directions = list(self.directions)
        self.push = inputs.push
        self.force_scale = d["force_scale"].to_numpy(float)
        self.pset = inputs.pset
        if postures is not None:                # tests = (posture, direction) pairs, labelled posture:direction
            self.test_postures = [p for p in postures for _ in self.base_directions]
            self.directions = [pair_label(p, n) for p in postures for n in self.base_directions]
            self.U = np.vstack([U] * len(postures))
            self.force_scale = np.tile(self.force_scale, len(postures))
        self.gamma = (np.array([float(opts.priorities.get(n, 0.0)) for n in self.muscles])
                      if opts.priorities else None)
        self.emg_options = emg_choices(self.muscles, cs.emg_groups, cs.decision.group_indices(self.muscles))
        self.emg_channels = resolve_emg_channels(opts.emg_channels, self.emg_options)
        self.opts = opts = replace(opts, emg_channels=self.emg_channels)
        self.gain_frac = float(opts.gain_frac) if opts.gain_frac is not None else cs.gain_frac
        self.seed = int(cs.seed if opts.seed is None else opts.seed)
        s = self.settings
        self.f0 = float(opts.prior_scale) * self.model.strengths
        self.skipped: list[str] = []
        self.entries: list[dict] = []          # effective measure/skip records, in order
        self._proposals: dict[tuple, Proposal] = {}
        self.log = SessionLog(self.out / LOG)
        self._seq = 0
        self.decision = None                   # the deficit decision (joint posterior sessions; in several postures too)
        if self.joint:                         # the joint posterior: candidates drawn and solved at start (N x K)
            self.sim = None
            what = (f"tests ({len(postures)} postures x {len(self.base_directions)} directions, change cost "
                    f"{cost:g} nats)" if postures else "directions")
            progress(f"joint posterior: {s.n_candidates} candidates x {len(self.directions)} {what} "
                     f"({self.model.name}), criterion {crit} ...")
            t0 = time.time()
            dec = self._decision_inputs(cs)
            worker = None
            if dec is not None and self.concurrent_decision and self.decision_process:
                from neckstrength.session.worker import DecisionProcess

                # built in its worker process while the joint posterior starts here
                worker = DecisionProcess().build_start(*dec, one_blas_thread=self.one_blas_thread)
            self.state = self._joint_state()
            self.key = self.state.key
            progress(f"  ready in {time.time() - t0:.1f} s")
            if dec is not None:
                t0 = time.time()
                self.decision = worker.build_wait() if worker is not None else self._decision(*dec)
                progress(f"deficit decision: {self.decision.settings.n_candidates} candidates per hypothesis, ready "
                         f"in {time.time() - t0:.1f} s")
            return
        ss = seed_sequence(self.seed, f"session/{opts.model}")
        F = sample_prior(self.f0, s.prior_sd_rel, s.n_candidates, generator(ss))
        grid = StrengthGrid.around(self.f0, s.prior_sd_rel, s.n_bins, s.bin_range_sd)
        self.key = sim_key(SimpleNamespace(F=F, U=U, grid=grid, iw=np.ones(len(F))))
        cache_dir = Path(opts.cache) if opts.cache else Path("results") / "session_cache"
        self.cache_path = cache_dir / f"{opts.model}_N{s.n_candidates}_{s.n_wbins}w_{s.n_bins}b_{self.key}.npz"
        self.sim = self._candidate_set(U, F, grid)
        self.state = SequentialState(self.model, self.sim, d["force_scale"].to_numpy(float), s, seed=self.seed)

    @_one_blas_thread
    def _joint_state(self):
        from neckstrength.sequential.joint_state import JointState

        rng = derive_rng(self.seed, f"session/{self.opts.model}/joint")
        if self.pset is None:
            return JointState(self.model, self.directions, self.U, self.force_scale, self.f0, self.settings, rng,
                              self.criterion, self.deficit, n_threads=self.threads)
        from neckstrength.postures.sequential import PostureJointPosterior

        post = PostureJointPosterior(self.pset, self.directions, self.U, self.force_scale, self.test_postures,
                                     self.f0, self.settings, rng, change_cost=self.opts.posture_change_cost,
                                     n_threads=self.threads)
        return JointState(self.model, self.directions, self.U, self.force_scale, self.f0, self.settings, rng,
                          self.criterion, self.deficit, posterior=post,
                          key_extra="postures=" + ",".join(self.postures) + f";cost={self.opts.posture_change_cost!r}")


    def _decision_inputs(self, cs) -> tuple[tuple, dict] | None:
        """The deficit decision's arguments (issue 31; :mod:`neckstrength.sequential.decision`; built beside the joint
        posterior by :meth:`_decision` or a worker process) for a model with the group; None otherwise."""
        over = {}
        if self.opts.prevalence is not None:
            over["prevalence"] = float(self.opts.prevalence)
        if self.opts.noise is not None:
            over["noise"] = float(self.opts.noise)
            over["noise_source"] = self.opts.noise_source or "given at session start"
        try:
            ds = replace(cs.decision, **over)
        except ValueError as exc:
            raise ValueError(f"session decision settings: {exc}") from None
        if not len(ds.group_indices(self.muscles)):
            return None
        post = {"pset": self.pset, "test_postures": self.test_postures} if self.postures else {}
        args = (self.model, self.directions, self.U, self.force_scale, self.f0, ds, self.settings,
                derive_rng(self.seed, f"session/{self.opts.model}/decision"))
        return args, {"n_threads": self.threads, **post}

    @_one_blas_thread
    def _decision(self, args: tuple, kw: dict):
        """The deficit decision in this process."""
        from neckstrength.sequential.decision import DeficitDecision

        return DeficitDecision(*args, **kw)

    @_one_blas_thread
    def _push(self, step) -> None:
        """Add a measurement to the estimate (and the decision). The joint posterior and the deficit decision are
        independent (own candidates, random streams and solver caches), so they are updated side by side, the
        decision in its worker process (:attr:`decision_process`) or a second thread: a step takes about the longer
        of the two, not their sum (same numbers)."""
        if not self.joint:
            self.state.steps.append(step)
            return
        dec = getattr(self, "decision", None)
        if dec is None or not self.concurrent_decision:
            self.state.push(step)
            if dec is not None:
                try:
                    dec.push(step.direction, step.force, step.activations)
                except Exception:
                    self.state.undo()
                    raise
            return
        ex = None
        if getattr(dec, "push_start", None) is not None:      # in its own process (session/worker.py)
            dec.push_start(step.direction, step.force, step.activations)
            wait = dec.push_wait
        else:                                                 # in a second thread
            from concurrent.futures import ThreadPoolExecutor

            ex = ThreadPoolExecutor(1)
            wait = ex.submit(dec.push, step.direction, step.force, step.activations).result
        err = None
        try:
            try:
                self.state.push(step)
            except Exception as exc:       # the joint posterior restored itself
                err = exc
            try:
                wait()
            except Exception:              # the decision restored itself; undo the joint posterior's step
                if err is None:
                    self.state.undo()
                raise
        finally:
            if ex is not None:
                ex.shutdown()
        if err is not None:
            dec.undo()
            raise err

    # -- candidate set: built once, cached on disk by its key
    def _candidate_set(self, U, F, grid) -> SimulatedSet:
        if self.cache_path.exists():
            try:
                sim = SimulatedSet.load(self.cache_path)
                if sim_key(sim) == self.key:
                    self.progress(f"candidate set: {sim.N} candidates x {sim.K} directions loaded from {self.cache_path}")
                    return sim
                self.progress(f"candidate set cache {self.cache_path} has another key; rebuilding")
            except Exception as exc:    # unreadable cache (e.g. killed while saving): rebuild
                self.progress(f"candidate set cache {self.cache_path} unreadable ({exc}); rebuilding")
        N, K = F.shape[0], U.shape[0]
        self.progress(f"building the candidate set once: {N} candidates x {K} directions ({self.model.name}) ...")
        done = threading.Event()
        t0 = time.time()

        def tick():
            while not done.wait(5.0):
                self.progress(f"  ... still building ({time.time() - t0:.0f} s)")

        th = threading.Thread(target=tick, daemon=True)
        th.start()
        try:
            sim, = SimulatedSet.build(self.model, self.directions, U, F, [grid], self.settings.n_wbins,
                                      progress=lambda s: self.progress("  " + s))
        finally:
            done.set()
            th.join()
        sim.save(self.cache_path)
        self.progress(f"  built in {time.time() - t0:.1f} s; cached in {self.cache_path}")
        return sim

    # -- header
    def header(self) -> dict:
        h = {"format": "neckstrength-session/1", "options": asdict(self.opts), "seed": self.seed,
             "settings": asdict(self.settings), "sim_key": self.key, "directions": self.directions,
             "muscles": self.muscles, "gain_frac": self.gain_frac}
        if getattr(self, "decision", None) is not None:
            h["decision"] = asdict(self.decision.settings)
        return h

    @classmethod
    def _open(cls, out: Path, opts: SessionOptions, progress: Callable[[str], None] | None,
              threads: int | None) -> "Session":
        """The engine for ``opts``: its settings and inputs built once from ``opts.config``
        (:func:`neckstrength.config.session_stage`)."""
        from neckstrength.config import load_config, session_stage

        settings, inputs = session_stage(load_config(opts.config), opts)
        return cls(out, opts, settings, inputs, progress, threads)

    @classmethod
    def create(cls, out: str | Path, opts: SessionOptions, progress: Callable[[str], None] | None = None,
               threads: int | None = None) -> "Session":
        """A new session in folder ``out`` (created; refused when it already holds a session): builds the candidates
        and writes ``session.json`` (the options, seed and settings that fix its numbers). Same as :meth:`start`."""
        return cls.start(out, opts, progress, threads)

    @classmethod
    def start(cls, out: str | Path, opts: SessionOptions, progress: Callable[[str], None] | None = None,
              threads: int | None = None) -> "Session":
        """A new session in folder ``out`` (see :meth:`create`)."""
        out = Path(out)
        if (out / LOG).exists() or (out / HEADER).exists():
            raise FileExistsError(f"{out} already holds a session; use `neckstrength session resume --out {out}`")
        out.mkdir(parents=True, exist_ok=True)
        s = cls._open(out, opts, progress, threads)
        tmp = out / (HEADER + ".tmp")
        tmp.write_text(json.dumps(s.header(), indent=2, sort_keys=True))
        os.replace(tmp, out / HEADER)
        return s

    @classmethod
    def resume(cls, out: str | Path, progress: Callable[[str], None] | None = None,
               threads: int | None = None) -> "Session":
        """The session in folder ``out`` as its log left it: the header's options rebuild the same candidates (refused
        when the config or package changed them), the verified log is replayed (a torn last line set aside and
        reported through ``progress``). Its :meth:`snapshot` equals the state before the pause."""
        progress = progress or _silent
        out = Path(out)
        if not (out / HEADER).exists():
            raise FileNotFoundError(f"{out}: no {HEADER}; start a session with `neckstrength session start`")
        h = json.loads((out / HEADER).read_text())
        o = dict(h["options"])
        o.setdefault("criterion", "thesis")     # sessions started before the joint posterior: the thesis's scheme
        s = cls._open(out, SessionOptions(**o), progress, threads)
        if s.key != h["sim_key"]:
            raise ValueError(f"{out}: the candidate set differs from the one the session started with (key "
                             f"{h['sim_key']}, now {s.key}); the config or the package changed")
        dec = getattr(s, "decision", None)
        if "decision" in h and (dec is None or json.loads(json.dumps(asdict(dec.settings))) != h["decision"]):
            raise ValueError(f"{out}: the deficit decision's settings differ from the ones the session started with "
                             f"({h['decision']}); the config (clinician.decision) changed")
        recs = s.log.read()                    # verified: seq and hash chain; a torn last line set aside
        if s.log.notice:
            progress(s.log.notice)
        s._seq = max((int(r.get("seq", 0)) for r in recs), default=0)
        for r in effective_entries(recs):
            s._apply(r)
        n_meas = sum(r["action"] == "measure" for r in s.entries)
        progress(f"resumed {out}: {len(recs)} log records replayed; {n_meas} measurements "
                 f"({', '.join(s.state.tested) or 'none'}), skipped: {', '.join(s.skipped) or 'none'}")
        return s

    # -- state changes (log first, then the estimate)
    @_one_blas_thread
    def _apply(self, r: dict) -> None:
        if r["action"] == "measure":
            step = self.state.likelihood(r["direction"], r["force_N"], r.get("activations"))
            self._push(step)
            if r["direction"] in self.skipped:
                self.skipped.remove(r["direction"])
        elif r["action"] == "skip":
            self.skipped.append(r["direction"])
        self.entries.append(r)

    @_one_blas_thread
    def _unapply(self) -> dict:
        r = self.entries.pop()
        if r["action"] == "measure":
            self.state.undo()
            if getattr(self, "decision", None) is not None:
                self.decision.undo()
            # proposals cached for tested sets with this measurement were computed from its force: a re-measurement
            # of the same test with another force must not reuse them (a resume would compute them afresh)
            self._proposals = {k: v for k, v in self._proposals.items() if r["direction"] not in k}
        else:
            self.skipped.remove(r["direction"])
        return r

    def accept(self, e: Entry) -> str:
        """Apply a validated entry: log (fsync'd) first, then update the estimate. Returns a one-line echo. A stop is
        logged only (:meth:`stop` also writes the summary)."""
        return self._accept(e)[0]

    def emg_info(self) -> dict:
        """The session's EMG channels (``channels``: None = not chosen, any muscle accepted), the ones the model
        offers (``choices``), and how an entry is used (``band``, ``label``)."""
        band = float(self.settings.emg_band)
        return {"channels": self.emg_channels, "choices": self.emg_options, "band": band,
                "label": (f"EMG: activation as a fraction of maximum (0-1); the estimate bounds the muscle's activation "
                          f"to the value +- {band:g} (config emg_band)")}

    def check_activations(self, activations: dict | None) -> None:
        """:class:`InputError` when ``activations`` names a muscle that is not one of the session's EMG channels
        (chosen at start; any muscle when none were chosen)."""
        if not activations or self.emg_channels is None:
            return
        for name in activations:
            if name not in self.emg_channels:
                raise InputError(f"EMG of {name} was not chosen for this session; its EMG channels: "
                                 f"{', '.join(self.emg_channels) or 'none (no EMG recorded)'}")

    def _accept(self, e: Entry) -> tuple[str, dict]:
        """(echo, the record as written to the log) of :meth:`accept`."""
        if e.kind == "measure":
            _check_direction(e.direction, self.directions, self.state.tested)
            self.check_activations(e.activations)
            # Algorithm 8 first (nothing changes yet), so that a failing computation never reaches the log
            step = self.state.likelihood(e.direction, e.force, e.activations)
            rec = {"action": "measure", "direction": e.direction, "force_N": e.force, "activations": e.activations}
            written = self.log.append(self._stamp(rec))
            self._push(step)
            if e.direction in self.skipped:
                self.skipped.remove(e.direction)
            self.entries.append(rec)
            act = "" if not e.activations else " with activations " + ", ".join(
                f"{k} {v:g}" for k, v in e.activations.items())
            what = ("posture {} / direction {}".format(*self.split(e.direction)) if self.postures else e.direction)
            return f"recorded {what}: {e.force:g} N{act}", written
        if e.kind == "skip":
            if e.direction not in self.directions or e.direction in self.state.tested or e.direction in self.skipped:
                raise InputError(f"cannot skip '{e.direction}': not an untested, unskipped test of this session")
            rec = {"action": "skip", "direction": e.direction}
            written = self.log.append(self._stamp(rec))
            self.skipped.append(e.direction)
            self.entries.append(rec)
            return (f"skipped {e.direction} (not proposed again; 'measure {e.direction} <force>' still records it)",
                    written)
        if e.kind == "undo":
            if not self.entries:
                raise InputError("nothing to undo")
            written = self.log.append(self._stamp({"action": "undo"}))
            r = self._unapply()
            what = f"measurement {r['direction']} ({r['force_N']:g} N)" if r["action"] == "measure" else \
                f"skip of {r['direction']}"
            return f"undone: {what}", written
        if e.kind == "stop":
            return "stopped", self.log.append(self._stamp({"action": "stop"}))
        raise InputError(f"'{e.kind}' is not an entry of the session (measure, skip, undo or stop)")

    def _stamp(self, rec: dict) -> dict:
        self._seq += 1
        return {"seq": self._seq, "time": time.strftime("%Y-%m-%dT%H:%M:%S"), **rec}

    # -- proposals (deterministic per set of tested directions)
    @_one_blas_thread
    def proposal(self) -> Proposal | None:
        if not self.state.remaining:
            return None
        key = tuple(sorted(self.state.tested))
        if key not in self._proposals:
            rng = derive_rng(self.seed, ";".join(key), 6)
            self._proposals[key] = self.state.propose(rng, self.gamma)
        return self._proposals[key]

    @_one_blas_thread
    def first_score(self) -> float:
        if () not in self._proposals:
            rng = derive_rng(self.seed, "", 6)
            fresh = (self._joint_state() if self.joint else
                     SequentialState(self.model, self.sim, self.state.force_scale, self.settings))
            self._proposals[()] = fresh.propose(rng, self.gamma)
        return float(self._proposals[()].table()["score"].max())

    def choice(self, p: Proposal | None) -> str | None:
        """The best remaining direction that has not been skipped (Eq. 6.7/6.8 score)."""
        if p is None:
            return None
        t = p.table()
        t = t[~t["direction"].isin(self.skipped)]
        return None if t.empty else str(t.loc[t["score"].idxmax(), "direction"])

    def _score_name(self) -> str:
        if self.criterion == "joint_eig":
            return "expected information gain"
        return "expected entropy reduction"

    def recommendation(self, p: Proposal | None) -> tuple[bool, str]:
        what = {"joint_eig": "expected information gain about the joint strengths",
                "marginal_entropy": "expected entropy reduction on the joint posterior (Eq. 6.7"
                                    f"{'/6.8' if self.gamma is not None else ''} score)",
                "thesis": f"expected entropy reduction (Eq. 6.7{'/6.8' if self.gamma is not None else ''} score)"}
        crit = f"criterion: best {what[self.criterion]} below {self.gain_frac:.0%} of the first step's"
        if p is None:
            return True, "STOP: every direction has been tested"
        best_dir = self.choice(p)
        if best_dir is None:
            return True, "STOP: every remaining direction has been skipped (measure one explicitly, undo, or stop)"
        t = p.table().set_index("direction")
        best, first = float(t.loc[best_dir, "score"]), self.first_score()
        ratio = best / first if first > 0 else 0.0
        if not self.state.tested:
            return False, f"continue: no measurement yet ({crit})"
        dec = getattr(self, "decision", None)
        if dec is not None and dec.decision() in ("deficit", "no deficit"):
            return True, (f"STOP recommended: the deficit question is decided ({dec.decision()}, P(deficit) "
                          f"{dec.p_deficit():.2f}); further tests would only refine the strength estimates")
        if ratio < self.gain_frac:
            return True, (f"STOP recommended: best {self._score_name()} {best:.3f} nats is {ratio:.0%} of the "
                          f"first step's {first:.3f} ({crit})")
        return False, (f"continue: best {self._score_name()} {best:.3f} nats is {ratio:.0%} of the first step's "
                       f"{first:.3f} ({crit})")

    @_one_blas_thread
    def estimate(self) -> pd.DataFrame:
        """The current estimate per muscle (a copy). Computed once per set of measurements: a screen, the snapshot
        and the predicted forces of one step share it (the key is the measurements' content, so an undo and a
        re-measurement with another force recompute it)."""
        key = tuple((r["direction"], r["force_N"], json.dumps(r.get("activations"), sort_keys=True))
                    for r in self.entries if r["action"] == "measure")
        memo = getattr(self, "_estimate_memo", None)
        if memo is None or memo[0] != key:
            # the joint posterior's estimate of this state was computed with its step (its history): not again
            e = self.state.history[-1]["estimate"].copy() if self.joint else self.state.estimate()
            e.insert(1, "f_0", self.f0)
            e.insert(2, "sd_0", self.settings.prior_sd_rel * self.f0)
            self._estimate_memo = memo = (key, e)
        return memo[1].copy()

    def uncertainty_label(self) -> str:
        """What the estimate's ± is and is not (shown with it on the screen and in :meth:`snapshot`)."""
        return ("The sd assumes the model fits every direction within the kernel width; on real participants it does "
                "not (docs/calibration.md): read it as a lower bound of the uncertainty, not a calibrated interval"
                + (" (tests in several postures: not checked by simulation, heuristic)" if self.postures
                   else " (on s3m24 it is not calibrated even on simulated data at session sizes)" if self.joint
                   else ""))

    def ranked(self, p: Proposal) -> pd.DataFrame:
        """The proposal's table (one row per remaining test: ``direction``, ``score``, per-muscle columns), best
        first. Ties (e.g. mirror-image directions) keep the direction order: the scores' last bits depend on which
        optimal LP vertex the solver's cache history returns, so a resumed session could swap them otherwise."""
        t = p.table()
        return t.assign(_key=t["score"].round(9)).sort_values("_key", ascending=False, kind="stable").drop(
            columns="_key")

    # -- display (text; :mod:`neckstrength.session.render`)
    def render(self) -> str:
        """The text screen of the current step (:func:`neckstrength.session.render.screen`)."""
        return render.screen(self)

    def prompt(self) -> str:
        return render.prompt(self)

    def decision_lines(self) -> list[str]:
        return render.decision_lines(self)

    def deficit_lines(self) -> list[str]:
        return render.deficit_lines(self)

    # -- the programmatic API (what a front end calls; the terminal uses the same calls)
    def parse(self, line: str) -> Entry:
        """A line as typed at the prompt -> an :class:`Entry` checked against this session (the proposed test, the
        tests and muscles, the postures); :class:`~neckstrength.errors.InputError` with the message to show."""
        return parse_entry(line, self.choice(self.proposal()), self.directions, self.state.tested, self.muscles,
                           self.postures, self.default_posture())

    @_one_blas_thread
    def propose(self) -> dict | None:
        """The proposed test and every remaining test with its expected information; None when every test is done.

        ``{"test": label or None (every remaining test skipped), "posture", "direction", "where": where the pad
        sits and which way the head pushes, "criterion", "score_name", "units": "nats", "alternatives": [{"test",
        "posture", "direction", "score", "gain", "posture_change", "skipped", "proposed", "per_muscle": {muscle:
        expected entropy reduction} or {}}, ...] best first}``. ``score`` is what the criterion ranks by:
        ``gain`` (the expected information) less ``posture_change_cost`` for a test in another posture. Proposals are
        deterministic per set of tested directions."""
        p = self.proposal()
        if p is None:
            return None
        prop = self.choice(p)
        cost = float(self.opts.posture_change_cost)
        now = self.state.post.current_posture if self.postures else "neutral"
        alts = []
        for r in self.ranked(p).to_dict("records"):
            post, d = self.split(r["direction"])
            change = bool(self.postures) and post != now
            alts.append({"test": r["direction"], "posture": post, "direction": d, "score": r["score"],
                         "gain": r["score"] + (cost if change else 0.0), "posture_change": change,
                         "skipped": r["direction"] in self.skipped, "proposed": r["direction"] == prop,
                         "per_muscle": {m: r[m] for m in self.muscles if m in r}})
        post, d = self.split(prop) if prop else (None, None)
        return _plain({"test": prop, "posture": post, "direction": d, "where": self.push.get(d, "") if d else "",
                       "criterion": self.criterion, "score_name": self._score_name(), "units": "nats",
                       "alternatives": alts})

    @_one_blas_thread
    def tell(self, entry: Entry | str) -> dict:
        """Apply one entry (an :class:`Entry`, or a line as typed at the prompt, see :meth:`parse`): the record is
        written and fsync'd to the log before the estimate changes and before this returns. Returns ``{"record":
        the log record as written (seq, time, action, direction, force_N, activations, prev), "message": the
        one-line echo}``; a stop also writes the outputs (see :meth:`stop`). A rejected entry raises
        :class:`~neckstrength.errors.InputError` and changes nothing."""
        if isinstance(entry, str):
            entry = self.parse(entry)
        if entry.kind == "help":
            raise InputError("'help' is a terminal command, not an entry (measure, skip, undo or stop)")
        if entry.kind == "stop":
            return self.stop()
        msg, rec = self._accept(entry)
        return {"record": rec, "message": msg}

    def undo(self) -> dict:
        """Undo the last measurement or skip (logged as an ``undo`` record); :meth:`tell`'s answer."""
        return self.tell(Entry("undo"))

    @_one_blas_thread
    def stop(self) -> dict:
        """Log ``stop`` and write ``summary.csv``, ``summary.png``, ``steps.csv`` and ``measurements.csv``; returns
        :meth:`tell`'s answer with ``"outputs"`` (their paths). A stopped session can be resumed and continued."""
        msg, rec = self._accept(Entry("stop"))
        paths = write_session(self.result(), self.out)
        return {"record": rec, "message": msg, "outputs": {k: str(v) for k, v in paths.items()}}

    @_one_blas_thread
    def predicted_forces(self, tests: Sequence[str]) -> np.ndarray:
        """The model's maximum force (N) in each test's direction (and posture) at the posterior-mean strengths
        ``f_c``, activations unconstrained (HiGHS, Eq. 4.1); a point prediction without uncertainty."""
        from neckstrength.wrench import solve

        idx = [self.directions.index(t) for t in tests]
        if not idx:
            return np.zeros(0)
        f = self.estimate()["f_c"].to_numpy(float)
        U = np.asarray(self.U)[idx]
        if self.pset is None:
            w, _, status = solve(self.model, f[None, :], U, method="highs", return_alpha=False)
        else:
            posts = np.array([self.test_postures[i] for i in idx])
            w, status = np.zeros((1, len(idx))), np.zeros((1, len(idx)), dtype=np.int64)
            for q in dict.fromkeys(posts):
                j = np.flatnonzero(posts == q)
                w[:, j], _, status[:, j] = solve(self.pset.models[q], (f * self.pset.rho[q])[None, :], U[j],
                                                 method="highs", return_alpha=False)
        out = w[0] / np.asarray(self.force_scale)[idx]
        return np.where(status[0] == 0, out, np.nan)

    @_one_blas_thread
    def snapshot(self) -> dict:
        """Everything a screen shows, as a plain JSON-serialisable dict (no NaN: missing values are None).

        Keys: ``format``, ``participant``, ``model``, ``criterion``, ``postures`` (None: neutral only), ``seed``,
        ``step`` (the step about to be taken, 1 + tests done), ``n_tested``, ``n_tests``, ``tests``, ``tested``,
        ``skipped``, ``remaining``; ``proposal`` (:meth:`propose`); ``estimate`` (``rows``: muscle, f_0, sd_0 prior,
        f_c, sd_c posterior mean and sd in N, entropy in nats; ``uncertainty_label``; ``calibrated``: False);
        ``measurements`` (in order: test, posture, direction, force_N, activations, predicted_N; with
        ``predicted_label``); ``deficit`` (P(deficit) of the configured group and its trend, with ``label`` and the
        screen's ``text``; None when the model lacks the group); ``emg`` (:meth:`emg_info`); ``decision`` (the deficit decision: decision,
        p_deficit, log_bf ± log_bf_se, misfit_rms, trend, ``settings`` and ``settings_label`` it depends on, ``label``,
        ``text``; None without one); ``recommendation`` (``stop``: bool, ``text``); ``screen`` (the terminal's text
        of this step). A resumed session's state equals the state before the pause."""
        p = self.proposal()
        stop, why = self.recommendation(p)
        e = self.estimate()
        meas = [r for r in self.entries if r["action"] == "measure"]
        pred = self.predicted_forces([r["direction"] for r in meas])
        trend = self.deficit_trend()
        deficit = None
        if trend and self.decision is None:
            h = self.state.history[-1] if self.joint else {}
            deficit = {"definition": self.deficit.label(), "p_deficit": trend[-1], "trend": trend,
                       "mc_se": h.get("p_deficit_se"), "calibrated": False,
                       "label": "NOT a calibrated probability (heuristic): checked only on simulated participants of "
                                "this model (docs/clinician.md), never under model misfit",
                       "text": render.deficit_lines(self)}
        decision = None
        if self.decision is not None:
            dec = self.decision
            h = dec.history[-1]
            decision = {"decision": h["decision"], "p_deficit": h["p_deficit"], "log_bf": h["log_bf"],
                        "log_bf_se": h["log_bf_se"], "misfit_rms": h.get("misfit_rms"),
                        "trend": [x["p_deficit"] for x in dec.history], "settings": dec.settings,
                        "settings_label": dec.settings.label(), "calibrated": dec.calibrated,
                        "p_model": h.get("p_model"),
                        "label": (f"P(deficit): {dec.p_label()}; the log Bayes factor's ± is its Monte Carlo error "
                                  "(heuristic); how well it decides: docs/clinician.md"),
                        "text": render.decision_lines(self)}
        return _plain({
            "format": "neckstrength-session-state/1", "participant": self.opts.participant, "model": self.model.name,
            "criterion": self.criterion, "postures": self.postures, "seed": self.seed,
            "step": len(self.state.tested) + 1, "n_tested": len(self.state.tested), "n_tests": len(self.directions),
            "tests": self.directions, "tested": self.state.tested, "skipped": self.skipped,
            "remaining": self.state.remaining, "proposal": self.propose(),
            "estimate": {"rows": e.to_dict("records"), "units": "N (entropy: nats)",
                         "uncertainty_label": self.uncertainty_label(), "calibrated": False},
            "measurements": [{"test": r["direction"], "posture": self.split(r["direction"])[0],
                              "direction": self.split(r["direction"])[1], "force_N": r["force_N"],
                              "activations": r.get("activations"), "predicted_N": float(v)}
                             for r, v in zip(meas, pred)],
            "predicted_label": "predicted_N: the model's maximum force in the test's direction at the posterior-mean "
                               "strengths f_c, activations unconstrained (a point prediction, no uncertainty)",
            "deficit": deficit, "decision": decision, "emg": self.emg_info(),
            "recommendation": {"stop": bool(stop), "text": why}, "screen": render.screen(self)})

    # -- P(deficit) of the configured group (clinician.deficit), with its trend
    def deficit_trend(self) -> list[float]:
        """P(deficit) before any test and after each measurement so far (empty if the model lacks the group)."""
        if getattr(self, "decision", None) is not None:
            return [h["p_deficit"] for h in self.decision.history]
        if not self.deficit.applies(self.muscles):
            return []
        if self.joint:
            return [h["p_deficit"] for h in self.state.history]
        from neckstrength.sequential.algorithms import posterior_from_loglik

        cum = np.zeros_like(self.state.log_prior)
        out = [self.deficit.probability_marginal(posterior_from_loglik(self.state.log_prior, cum), self.sim.grid,
                                                 self.f0, self.muscles)]
        for st in self.state.steps:
            cum = cum + st.loglik
            out.append(self.deficit.probability_marginal(posterior_from_loglik(self.state.log_prior, cum),
                                                         self.sim.grid, self.f0, self.muscles))
        return out

    def split(self, label: str) -> tuple[str, str]:
        """(posture, direction) of a test label ('neutral' for a plain direction)."""
        return split_label(label)

    def default_posture(self) -> str:
        """The posture a bare direction at the prompt is taken in: the proposed test's, else the last test's."""
        if not self.postures:
            return "neutral"
        prop = self.choice(self.proposal())
        return self.split(prop)[0] if prop else self.state.post.current_posture

    @_one_blas_thread
    def result(self) -> SessionResult:
        """The session's result so far, in memory (:class:`~neckstrength.session.stage.SessionResult`: the estimate
        per muscle, the per-step trajectory, the measurements in order, their header lines); :meth:`stop` writes it
        with :func:`~neckstrength.session.stage.write_session`."""
        e = self.estimate()
        hdr = [f"clinician session: participant {self.opts.participant}, model {self.model.name}, "
               f"{len(self.state.tested)} of {len(self.directions)} directions: {', '.join(self.state.tested)}",
               (f"joint posterior, criterion {self.criterion}, N {self.settings.n_candidates}, kernel noise_rel "
                f"{self.settings.noise_rel}; " if self.joint else
                f"N_F {self.settings.n_candidates}, N_S {self.settings.n_sim}, bins {self.settings.n_bins}; ")
               + "prior f_0 = "
               f"{self.opts.prior_scale:g} f'_base, sd 0.3 f_0; seed {self.seed}; candidate key {self.key}",
               "f_c = posterior mean, sd_c = posterior sd (N; not calibrated under model misfit, docs/calibration.md); "
               "entropy in nats (Eq. 6.3)"]
        if self.decision is not None:
            dec = self.decision
            hdr.append(f"deficit decision: {dec.decision()}, P(deficit) {dec.p_deficit():.3f} ({dec.p_label()}), "
                       f"log Bayes factor {dec.log_bf():+.2f} ± {dec.log_bf_se():.2f} (Monte Carlo, heuristic); "
                       f"{dec.settings.label()}; how well it decides: docs/clinician.md")
        # per-step trajectory (iteration 0 = prior)
        rows = []
        pdef = self.deficit_trend()
        if self.joint:
            for t, h in enumerate(self.state.history):
                for r in h["estimate"].to_dict("records"):
                    rows.append({"step": t, "direction": h["direction"], "force_N": h["force"], "muscle": r["muscle"],
                                 "f_c": r["f_c"], "sd_c": r["sd_c"], "entropy": r["entropy"]})
        steps = [] if self.joint else list(self.state.steps)
        from neckstrength.sequential.algorithms import pdf_moments, posterior_from_loglik
        cum = None if self.joint else np.zeros_like(self.state.log_prior)
        for t in range(0 if self.joint else len(steps) + 1):
            if t:
                cum = cum + steps[t - 1].loglik
            pdf = posterior_from_loglik(self.state.log_prior, cum)
            E, V = pdf_moments(pdf, self.sim.grid)
            H = pdf_entropy(pdf, self.sim.grid)
            for j, m in enumerate(self.muscles):
                rows.append({"step": t, "direction": steps[t - 1].direction if t else "",
                             "force_N": steps[t - 1].force if t else np.nan, "muscle": m, "f_c": E[j],
                             "sd_c": np.sqrt(V[j]), "entropy": H[j]})
        traj = pd.DataFrame(rows)
        if pdef:
            traj["p_deficit"] = np.asarray(pdef)[traj["step"].to_numpy()]
            if getattr(self, "decision", None) is not None:
                hist = pd.DataFrame(self.decision.history)
                for c in ("log_bf", "log_bf_se", "p_deficit_se", "decision"):
                    traj[c] = hist[c].to_numpy()[traj["step"].to_numpy()]
            elif self.joint:
                se = [h.get("p_deficit_se", np.nan) for h in self.state.history]
                traj["p_deficit_mc_se"] = np.asarray(se)[traj["step"].to_numpy()]
        meas = [r for r in self.entries if r["action"] == "measure"]
        mdf = pd.DataFrame({"direction": [r["direction"] for r in meas], "force_N": [r["force_N"] for r in meas],
                            "activations": [",".join(f"{k}:{v:g}" for k, v in (r.get("activations") or {}).items())
                                            for r in meas]})
        if self.postures:                       # posture column, direction without the posture prefix
            pairs = [self.split(r["direction"]) for r in meas]
            mdf["direction"] = [d for _, d in pairs]
            mdf.insert(0, "posture", [p for p, _ in pairs])
        return SessionResult(e, hdr, traj, mdf, [f"measurements of session {self.out.name} "
                                                 "(replay: neckstrength session replay --csv ...)"],
                             f"{self.opts.participant} · {self.model.name}")

    def write_summary(self) -> tuple[Path, Path]:
        """Write :meth:`result` (:func:`~neckstrength.session.stage.write_session`): ``summary.csv`` (estimate per
        muscle) and ``summary.png``; also ``steps.csv`` and ``measurements.csv`` (the measurements in order, in the
        format :func:`~neckstrength.session.repl.replay_csv` reads). Returns the paths of the first two."""
        paths = write_session(self.result(), self.out)
        return paths["summary_csv"], paths["summary_png"]


def _plain(x):
    """``x`` as JSON-ready Python: dicts, lists, str, int, float (NaN and inf as None), bool, None."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return [_plain(v) for v in x.tolist()]
    if hasattr(x, "__dataclass_fields__") and not isinstance(x, type):
        return _plain(asdict(x))
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if x is None or isinstance(x, str):
        return x
    if isinstance(x, Path):
        return str(x)
    return str(x)
