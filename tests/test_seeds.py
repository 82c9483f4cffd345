"""One seed convention (issue 33, item 4): every random stream goes through ``neckstrength.seeds``.

The grep over ``src/neckstrength`` fails on a new bypass: a generator or seed sequence built outside ``seeds.py``
(``default_rng``, ``SeedSequence``, ``RandomState``, a bit generator, ``crc32``, numpy's global random functions) and a
literal stream key whose template is not registered in ``seeds.STREAMS``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from neckstrength import seeds
from neckstrength.seeds import STREAMS, derive_rng, generator, registered, seed_sequence, skeleton

SRC = Path(__file__).resolve().parents[1] / "src" / "neckstrength"
BANNED = {"default_rng", "SeedSequence", "RandomState", "Generator", "PCG64", "PCG64DXSM", "MT19937", "Philox",
          "SFC64", "crc32"}
#: numpy's global-state functions (np.random.<name>(...)) that would draw from an unseeded stream
GLOBAL_STATE = {"seed", "rand", "randn", "randint", "random", "random_sample", "choice", "permutation", "shuffle",
                "normal", "uniform", "standard_normal", "integers", "lognormal", "exponential", "poisson", "binomial",
                "get_state", "set_state"}
#: (file, name) allowed for now, each with its reason
ALLOWED: dict[tuple[str, str], str] = {}


def _py_files():
    return sorted(p for p in SRC.rglob("*.py") if p.name != "seeds.py")


def _name(func: ast.expr) -> str | None:
    return func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None


def _is_np_random(func: ast.expr) -> bool:  # np.random.<x> / numpy.random.<x>
    v = func.value if isinstance(func, ast.Attribute) else None
    return (isinstance(v, ast.Attribute) and v.attr == "random" and isinstance(v.value, ast.Name)
            and v.value.id in ("np", "numpy"))


def _key_text(node: ast.expr) -> str | None:
    """A literal key or f-string as a template ('{}' for each field); None when the key is built elsewhere."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value
    if isinstance(node, ast.JoinedStr):
        return "".join(v.value if isinstance(v, ast.Constant) else "{}" for v in node.values)
    return None


def _scan():
    bypasses, keys, literals = [], [], set()
    for p in _py_files():
        rel = p.relative_to(SRC).as_posix()
        tree = ast.parse(p.read_text(), str(p))
        for node in ast.walk(tree):
            if isinstance(node, (ast.Constant, ast.JoinedStr)):
                t = _key_text(node)
                if t is not None:
                    literals.add(skeleton(t))
            mods = ([a.name for a in node.names] if isinstance(node, ast.Import)
                    else [node.module] if isinstance(node, ast.ImportFrom) else [])
            bypasses += [f"{rel}:{node.lineno}: imports {m}" for m in mods if m in ("random", "zlib")]
            if not isinstance(node, ast.Call):
                continue
            name = _name(node.func)
            if name in BANNED or (_is_np_random(node.func) and name in GLOBAL_STATE):
                if (rel, name) not in ALLOWED:
                    bypasses.append(f"{rel}:{node.lineno}: {ast.unparse(node)[:100]}")
            if name in ("derive_rng", "seed_sequence") and len(node.args) >= 2:
                t = _key_text(node.args[1])
                if t is not None:
                    keys.append((rel, node.lineno, t))
    return bypasses, keys, literals


def test_no_generator_or_seed_built_outside_seeds_py():
    bypasses, _, _ = _scan()
    assert not bypasses, ("random streams built outside neckstrength.seeds (use derive_rng(seed, key) with a key "
                          "registered in seeds.STREAMS, or seeds.generator(seed_sequence)):\n" + "\n".join(bypasses))


def test_every_literal_stream_key_is_registered():
    _, keys, _ = _scan()
    assert len(keys) >= 20, keys  # the scan sees the project's streams
    missing = [f"{rel}:{line}: '{t}'" for rel, line, t in keys if registered(t) is None]
    assert not missing, "stream keys not registered in neckstrength.seeds.STREAMS:\n" + "\n".join(missing)


def test_every_registered_key_is_used():
    _, _, literals = _scan()
    for p in (SRC.parents[1] / "benchmarks").glob("*.py"):  # a stream handed into src/ by a benchmark
        literals |= {skeleton(t) for n in ast.walk(ast.parse(p.read_text())) if (t := _key_text(n)) is not None}
    unused = [k for s in STREAMS for k in s.keys if skeleton(k) not in literals]
    assert not unused, f"registered stream keys no module spells out (stale registry entries): {unused}"


def test_registered_keys_are_unique():
    sk = [skeleton(k) for s in STREAMS for k in s.keys]
    assert len(sk) == len(set(sk))


def test_the_scan_catches_a_bypass(tmp_path, monkeypatch):
    """The grep is not vacuous: a module with a literal seed and an unregistered key is reported."""
    (tmp_path / "bad.py").write_text("import numpy as np\nfrom neckstrength.seeds import derive_rng\n"
                                     "r = np.random.default_rng(0)\nq = derive_rng(1, f'nowhere/{r}')\n"
                                     "np.random.seed(3)\n")
    monkeypatch.setattr(__import__(__name__), "SRC", tmp_path)
    bypasses, keys, _ = _scan()
    assert len(bypasses) == 2 and [registered(t) for _, _, t in keys] == [None]


def test_derivation_and_root_streams():
    a = derive_rng(7, "gap/folds/S003").integers(0, 2**31, 5)
    b = np.random.default_rng(np.random.SeedSequence([7, 0xFFFFFFFF & __import__("zlib").crc32(b"gap/folds/S003")]))
    assert (a == b.integers(0, 2**31, 5)).all()
    # root streams are what default_rng(seed) gives (the Chapter 3 cohort and the example lab are unchanged)
    assert (derive_rng(20261123, "chapter3/synthetic").normal(size=3)
            == np.random.default_rng(20261123).normal(size=3)).all()
    assert seeds.describe(5, "trials/example") == "SeedSequence(5)"
    with pytest.raises(ValueError):
        seed_sequence(5, "trials/example", 1)


def test_generator_refuses_an_integer():
    with pytest.raises(TypeError, match="SeedSequence"):
        generator(5)
    ss = seed_sequence(1, "coverage/p2m7")
    assert (generator(ss).random(2) == np.random.default_rng(seed_sequence(1, "coverage/p2m7")).random(2)).all()


def test_runinfo_reads_the_registry():
    from neckstrength.report.runinfo import seed_rows

    rows = seed_rows(20261123, True, [("p2m7", "S003")])
    streams = [r for r in rows if r["kind"] == "stream"]
    assert len(streams) == len(STREAMS)
    c3 = next(r for r in rows if r["name"] == "chapter3 SYNTHETIC cohort")
    assert c3["value"] == "SeedSequence(20261123)"
