"""Every random stream of the project, derived from one seed and a stable text key.

``SeedSequence([seed, crc32(key), *extra])``: the same key gives the same stream on every path (pipeline,
command line, a batch call) and in any order; different keys give independent streams.
:mod:`neckstrength.config` re-exports these; modules below it (e.g. :mod:`neckstrength.gap`) import them here.
"""

from __future__ import annotations

import zlib

import numpy as np


def seed_sequence(seed: int, key: str | bytes, *extra: int) -> np.random.SeedSequence:
    """The one derivation of the project's random streams: ``SeedSequence([seed, crc32(key), *extra])``."""
    key = key.encode() if isinstance(key, str) else key
    return np.random.SeedSequence([int(seed), zlib.crc32(key), *extra])


def derive_rng(seed: int, key: str | bytes, *extra: int) -> np.random.Generator:
    """``numpy.random.default_rng(seed_sequence(seed, key, *extra))``."""
    return np.random.default_rng(seed_sequence(seed, key, *extra))
