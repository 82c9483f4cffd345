"""Run-to-run spread of the Bayes evidence's decision (issue 32): the same data, other random streams.

The evidence draws random numbers for the base fit's starts, the refits' starts and the element null's draws; the
diagnosis seeds them from the config's seed and the data set's name (``gap/evidence/{name}``). This script takes
cases of a user-benchmark design (``bench_gap_users.py``'s generator and stream) and runs the evidence with
``--streams`` other streams, (a) as shipped and (b) with the base fit held at the best of ``--fit-starts`` starts,
and prints, per case, P(no effect) and the named effect of each stream: how often the decision depends on the
stream, and whether the base fit is the part that moves it.

    .venv/bin/python benchmarks/bench_gap_evidence_stability.py --config CONFIG_WITH_THE_DESIGN_SEED \
        --cases u019,u056 --streams 6 [--valley 41]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))


def valley(ex, case, y, sigma, n: int, rng) -> None:
    """The base fits of ``n`` starts (the baseline and ``n - 1`` random ones, as :meth:`Explanations.fit` draws
    them), their MAP losses, the largest log-strength difference of the next best from the best, and the evidence at
    the four best."""
    c0 = time.process_time()
    fits = ex.fit(y, sigma, rng, n_random=n - 1, return_all=True)
    cpu = (time.process_time() - c0) / n
    loss = np.array([f[1] for f in fits])
    order = np.argsort(loss)
    logf = np.array([np.log(f[0]) for f in fits])
    far = [float(np.abs(logf[k] - logf[order[0]]).max()) for k in order[1:6]]
    print(f"{case.name} valley: {n} base fits ({cpu:.3f} s CPU each), best MAP losses "
          f"{', '.join(f'{v:.3g}' for v in loss[order][:6])}; next best from the best (max abs log strength) "
          f"{', '.join(f'{v:.2f}' for v in far)}", flush=True)
    for k in order[:4]:
        r = ex.evidence(case.forces, sigma, np.random.default_rng(1), strengths=fits[k][0])
        print(f"  loss {loss[k]:.3g}: P(no effect) {r.p_no_effect:.2g}, named {r.named}", flush=True)


def main(argv=None) -> pd.DataFrame:
    from bench_gap_users import add_design_args, design_from_args, finish

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_design_args(ap)
    ap.add_argument("--cases", required=True, help="comma-separated case names (u001, ...)")
    ap.add_argument("--streams", type=int, default=6)
    ap.add_argument("--fit-starts", type=int, default=60, help="starts of the held base fit in (b)")
    ap.add_argument("--valley", type=int, default=0, help="also: this many base fits from random starts per case, "
                    "their MAP losses, how far apart the best ones lie, and the evidence at the four best")
    ap.add_argument("--out", default=None, help="CSV of the per-case, per-stream table")
    a = ap.parse_args(argv)
    from neckstrength.gap import evidence as ev
    from neckstrength.seeds import derive_rng

    t0, c0 = time.perf_counter(), time.process_time()
    cfg, case_list, ctx, ds = design_from_args(a)
    cases = {c.name: c for c in case_list}
    unknown = [n for n in a.cases.split(",") if n not in cases]
    if unknown:
        raise SystemExit(f"--cases: no {', '.join(unknown)} in this design ({len(cases)} cases)")
    es = ds.evidence
    ex = ev.Explanations(ctx, list(ds.effects), es)
    rows = []
    for name in a.cases.split(","):
        c = cases[name]
        y, s = np.log(c.forces), float(c.noise_sd)
        ex.s = replace(es, fit_starts=int(a.fit_starts))
        held = ex.fit(y, s, derive_rng(ds.seed, f"stability/{name}"))
        ex.s = es
        for k in range(a.streams):
            for mode, f in (("shipped", None), ("base fit held", held)):
                r = ex.evidence(c.forces, s, derive_rng(ds.seed, f"stability/{name}/{k}"), strengths=f)
                rows.append({"case": name, "truth": c.truth, "mode": mode, "stream": k,
                             "p_no_effect": r.p_no_effect, "named": r.named, "best_effect": r.best_effect,
                             "log_strength_norm": float(np.linalg.norm(np.log(r.strengths)))})
        if a.valley:
            valley(ex, c, y, s, int(a.valley), derive_rng(ds.seed, f"stability/{name}/valley"))
        tab = pd.DataFrame([r for r in rows if r["case"] == name])
        for mode, g in tab.groupby("mode", sort=False):
            print(f"{name} ({c.truth}) {mode}: " + ", ".join(f"{p:.2g} {n}" for p, n in zip(g.p_no_effect, g.named)),
                  flush=True)
    tab = pd.DataFrame(rows)
    flips = tab.groupby(["mode", "case"])["named"].nunique().gt(1).groupby("mode").sum()
    print("\ncases whose named effect depends on the stream: " + "; ".join(f"{m} {int(v)} of {a.cases.count(',') + 1}"
                                                                           for m, v in flips.items()))
    return finish(tab, a.out, t0, c0)


if __name__ == "__main__":
    main()
