"""Why a printed value differs: the same estimator rerun with one input changed at a time (issue 36 item 2).

A variant is a name and a set of config changes (dotted key -> value); :func:`apply_variant` checks that every key
exists (an unknown key is an error naming the variant) and returns the changed config, which the caller validates
against the schema. The scoring of the variants' runs against the print is
:func:`neckstrength.report.scorecard.distribution.attribution_summary`.
"""

from __future__ import annotations

import copy
from typing import Any, Mapping


def apply_variant(config: Mapping, name: str, changes: Mapping[str, Any]) -> dict:
    """A deep copy of ``config`` with ``changes`` applied; every dotted key must exist in ``config``."""
    out = copy.deepcopy(dict(config))
    for dotted, value in changes.items():
        node = out
        *parents, leaf = str(dotted).split(".")
        for i, k in enumerate(parents):
            if not isinstance(node, dict) or k not in node:
                raise KeyError(f"reruns.attribution.variants.{name}: unknown setting "
                               f"'{'.'.join(parents[:i + 1])}' (in '{dotted}')")
            node = node[k]
        if not isinstance(node, dict) or leaf not in node:
            raise KeyError(f"reruns.attribution.variants.{name}: unknown setting '{dotted}'")
        node[leaf] = copy.deepcopy(value)
    return out
