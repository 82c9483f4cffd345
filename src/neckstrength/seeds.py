"""Every random stream of the project: one derivation, one registry of stream keys.

A stream is ``SeedSequence([seed, crc32(key), *extra])`` (:func:`seed_sequence`): ``seed`` is the config ``seed``
(recorded in every table header), ``key`` a stable text naming what the stream draws. The same key gives the same
stream on every path (pipeline, command line, a batch call) and in any order; different keys give independent
streams. Science takes the result as a ``numpy.random.Generator`` or ``SeedSequence`` argument (or, in the gap
package, derives its keyed streams from the settings' ``seed`` through this module).

:data:`STREAMS` registers every key template used in ``src/neckstrength`` with where it is drawn and what for;
:mod:`neckstrength.report.runinfo` reads it for the report's seed table. Three keys are *root* streams,
``SeedSequence(seed)`` (what ``numpy.random.default_rng(seed)`` gives): the Chapter 3 SYNTHETIC cohort and the
example lab were drawn that way before the registry existed, and keeping them keeps the shipped tables and the
README's walk-through unchanged; the solver cache's hash weights are a fixed constant, not a drawn result.

No other module builds a generator or a seed sequence: ``tests/test_seeds.py`` fails on ``default_rng``,
``SeedSequence``, ``RandomState``, ``crc32`` or numpy's global random functions outside this module, and on a
literal key whose template is not registered here.
:mod:`neckstrength.config` re-exports :func:`seed_sequence` and :func:`derive_rng`.
"""

from __future__ import annotations

import re
import zlib
from dataclasses import dataclass

import numpy as np

#: the seed of the solver cache's hash weights (a constant of the code, not a setting)
HASH_SEED = 20261123


@dataclass(frozen=True)
class Stream:
    """A registered stream: its key template(s) (``{field}`` placeholders), ``extra`` integers appended after the
    key's crc32 (empty: none), where it is drawn (``by``) and what it draws (``what``). ``root``: derived as
    ``SeedSequence(seed)`` instead (see the module docstring)."""

    keys: tuple[str, ...]
    by: str
    what: str
    extra: str = ""
    root: bool = False


STREAMS: tuple[Stream, ...] = (
    # root streams (kept as drawn before the registry)
    Stream(("chapter3/synthetic",), "pipeline.chapter3.chapter3_synthetic_cohort",
           "the Chapter 3 SYNTHETIC per-ROI MFI cohort", root=True),
    Stream(("trials/example",), "trials.synthetic.generate_example (seed: neckstrength example-lab --seed)",
           "the example lab's trials (efforts, trial noise, direction errors)", root=True),
    Stream(("wrench/hash_weights",), "wrench.batched (seed: HASH_SEED)",
           "the solver cache's hash weights (a constant; no result depends on them)", root=True),
    # Chapter 5
    Stream(("{model}/{dataset}",), "pipeline.chapter5.chapter5_estimate, estimate (participant as data set)",
           "Algorithm 4: only the subsample of candidates stored for plotting (the algorithm is deterministic)"),
    Stream(("smc/{model}/{dataset}",), "pipeline.chapter5.chapter5_smc, estimate --method smc", "ABC-SMC"),
    Stream(("coverage/{model}",), "pipeline.chapter5.chapter5_coverage", "the coverage study's simulated truths"),
    # Chapter 6
    Stream(("chapter6/{model}/{dataset}",), "pipeline.chapter6.chapter6_run",
           "spawned in two: the prior candidates, the proposals (and the sampled orders)"),
    Stream(("chapter6/order_comparison",), "pipeline.chapter6 (order comparison)",
           "one child per participant, each spawned in three: truth, prior, proposals"),
    Stream(("chapter6/criteria/{model}",), "pipeline.chapter6 (criteria comparison)",
           "one child per participant, each spawned in four: truth, candidates, proposals, thesis scheme"),
    Stream(("chapter6/joint/{model}/{dataset}",), "pipeline.chapter6.chapter6_joint, estimate --method joint",
           "spawned in two: the joint estimator's candidates and proposals"),
    # run-to-run reruns
    Stream(("reruns/chapter5/{model}/{dataset}", "reruns/chapter6/{model}/{dataset}"),
           "reruns.runs.member_stream", "rerun member k of a Chapter 5 / 6 run (member 0 is the pipeline's own "
           "stream, key '{model}/{dataset}' / 'chapter6/{model}/{dataset}')", extra="member k >= 1"),
    Stream(("reruns/band_chance",), "report.scorecard.distribution.band_chance_rate",
           "the permutations of the run-to-run bands' chance rate"),
    # report
    Stream(("{test}",), "report.scorecard.chance.chance_rates",
           "the permutations of one conclusion test's chance rate (key: the test's name)"),
    Stream(("scorecard/rank/{table}|{dataset}",), "report.scorecard.estimates",
           "the permutations of a participant's Spearman rank p-value (key: table path and data set)"),
    # calibration, postures, identifiability, clinician
    Stream(("calibration/{model}/{method}",), "pipeline.calibration (SBC)", "replicate i's truth and sampler",
           extra="replicate i"),
    Stream(("calibration/misfit/{model}/{kind}",), "pipeline.calibration (misfit coverage)",
           "replicate i's truth and sampler", extra="replicate i"),
    Stream(("postures/compare/{model}",), "pipeline.postures.postures_compare",
           "spawned in three: simulated participants, measurement noise, one child per participant's runs"),
    Stream(("postures/smc/{model}", "postures/smc/{model}/{arm}"), "pipeline.postures (ABC-SMC comparison)",
           "the simulated participant; each arm's sampler"),
    Stream(("identifiability/{model}/{what}",), "pipeline.identifiability", "one profile study's draws"),
    Stream(("clinician/{model}/{what}",), "pipeline.clinician (deficit study)", "patient i's truth, candidates, "
           "proposals", extra="patient i"),
    Stream(("decision/{model}/{what}",), "pipeline.clinician (decision study)", "patient i's truth, candidates, "
           "proposals", extra="patient i"),
    Stream(("crosscheck/{case}",), "calibration.crosscheck (benchmarks/bench_pyabc_crosscheck.py; case: model/dataset)",
           "our ABC-SMC; pyABC's global numpy state (seed_numpy_global)"),
    Stream(("estimate/{model}/decision",), "estimate", "the deficit decision's two samplers"),
    # gap diagnosis
    Stream(("gap-benchmark/{model}",), "pipeline.gap (benchmark)", "the benchmark's simulated cases"),
    Stream(("gap/folds/{dataset}",), "gap.diagnose, gap.calibrate", "the cross-validation folds of the directions"),
    Stream(("gap/bootstrap/{dataset}",), "gap.diagnose", "the bootstrap over directions (P(best))"),
    Stream(("gap/reach/{dataset}",), "gap.diagnose", "the reach (power) simulation"),
    Stream(("gap/truth/{dataset}", "gap/truth/{dataset}/{tag}"), "gap.calibrate", "the calibration's truths"),
    Stream(("gap/power/{dataset}/{effect}/{size}",), "gap.calibrate", "the power simulation's noise"),
    Stream(("gap/null/{dataset}",), "gap.calibrate", "the null simulation's noise (key + '/{tag}' for a tagged null)"),
    Stream(("gap/elements/{dataset}",), "gap.calibrate (null_truth: elements)",
           "the element null's strength factors per element and replicate (key + '/{tag}' for a tagged null)"),
    Stream(("gap/starts/{key}/{dataset}",), "gap.engine", "a refit's random starts", extra="fold + 1"),
    Stream(("gap/scatter/{dataset}",), "gap.diagnose (aiming scatter)", "the aiming-scatter test's simulation"),
    Stream(("gap/evidence/prior/{effect}",), "gap.evidence.prior_points (seed: HASH_SEED)",
           "the quasi-random points of an effect's parameter box (a constant quadrature rule)"),
    Stream(("gap/evidence/{dataset}",), "gap.diagnose (the evidence's second reading)",
           "the element null's draws of the Bayes evidence (gap.evidence)"),
    # clinician session (neckstrength session, the app)
    Stream(("session/{model}",), "session.state", "the prior candidates (spawned)"),
    Stream(("session/{model}/joint",), "session.state", "the joint estimator"),
    Stream(("session/{model}/decision",), "session.state", "the deficit decision's samplers"),
    Stream(("",), "session.state (proposals)",
           "the next-test proposal given the tested directions (key: their names joined by ';', '' before the first)",
           extra="6"),
)

_ROOT_KEYS = frozenset(k for s in STREAMS if s.root for k in s.keys)


def skeleton(template: str) -> str:
    """A key template with every ``{field}`` replaced by ``{}`` (how :data:`STREAMS` entries are matched)."""
    return re.sub(r"\{[^{}]*\}", "{}", template)


def registered(key_template: str) -> Stream | None:
    """The registered stream whose key template has the skeleton of ``key_template`` (None: not registered)."""
    sk = skeleton(key_template)
    for s in STREAMS:
        if any(skeleton(k) == sk for k in s.keys):
            return s
    return None


def seed_sequence(seed: int, key: str | bytes, *extra: int) -> np.random.SeedSequence:
    """The one derivation of the project's random streams: ``SeedSequence([seed, crc32(key), *extra])``
    (``SeedSequence(seed)`` for the registered root keys)."""
    if isinstance(key, str) and key in _ROOT_KEYS:
        if extra:
            raise ValueError(f"root stream '{key}' takes no extra integers")
        return np.random.SeedSequence(int(seed))
    key = key.encode() if isinstance(key, str) else key
    return np.random.SeedSequence([int(seed), zlib.crc32(key), *extra])


def derive_rng(seed: int, key: str | bytes, *extra: int) -> np.random.Generator:
    """``numpy.random.default_rng(seed_sequence(seed, key, *extra))``."""
    return np.random.default_rng(seed_sequence(seed, key, *extra))


def generator(stream: np.random.SeedSequence | np.random.Generator) -> np.random.Generator:
    """A generator on a stream handed down by the caller (a :func:`seed_sequence` or one of its ``spawn`` children;
    a generator is returned as it is). An integer is refused: it would bypass the registry."""
    if isinstance(stream, np.random.Generator):
        return stream
    if not isinstance(stream, np.random.SeedSequence):
        raise TypeError(f"a random stream is a numpy SeedSequence from neckstrength.seeds (got {type(stream).__name__}"
                        f" {stream!r}); derive it with seed_sequence(seed, key)")
    return np.random.default_rng(stream)


def child_generators(rng: np.random.Generator, n: int) -> list[np.random.Generator]:
    """``n`` independent generators spawned from ``rng``'s seed sequence (a generator without one: seeded from
    ``rng``'s own draws)."""
    ss = getattr(rng.bit_generator, "seed_seq", None)
    if ss is not None:
        return [np.random.default_rng(s) for s in ss.spawn(n)]
    return [np.random.default_rng(rng.integers(2 ** 63)) for _ in range(n)]


def seed_numpy_global(stream: np.random.SeedSequence) -> None:
    """Seed numpy's global random state from ``stream``, for a third-party library that draws from it (pyABC):
    ``numpy.random.seed`` with the stream's first 32-bit word."""
    if not isinstance(stream, np.random.SeedSequence):
        raise TypeError("a random stream is a numpy SeedSequence from neckstrength.seeds "
                        f"(got {type(stream).__name__})")
    np.random.seed(int(stream.generate_state(1)[0]))


def describe(seed: int | None, key: str, *extra: int) -> str:
    """The derivation of stream ``key`` as text, e.g. ``SeedSequence([20261123, 123456789])`` (for run records)."""
    if key in _ROOT_KEYS:
        return f"SeedSequence({seed})"
    return f"SeedSequence([{', '.join(str(x) for x in (seed, zlib.crc32(key.encode()), *extra))}])"
