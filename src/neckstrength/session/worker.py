"""The session's deficit decision in a worker process (speed only: the same numbers as in the session's process).

The joint posterior and the deficit decision's two samplers are independent (own candidates, random streams and
solver caches) and a step updates both. In threads of one process they share Python's interpreter lock, which the
samplers' Metropolis-Hastings moves hold most of the time (bookkeeping around many small LP batches; about 80% of the
decision's and 60% of the joint posterior's CPU time on s3m24): a step then took about the sum of the two, not the
longer. :class:`DecisionProcess` runs the :class:`~neckstrength.sequential.decision.DeficitDecision` in a Python
process of its own (``python -m neckstrength.session.worker``, started with the session so that its imports overlap
the joint posterior's start), built there from the same inputs and random state, so the two update side by side on two
cores. It offers what the session reads of a decision (``settings``, ``history``, ``push``, ``undo``, ``p_deficit``,
``log_bf``, ``decision``, ...); every call runs the same code on the same state as in the session's process, so the
numbers are the same (tests/session/test_state_joint.py). The worker stops with its session object or its process.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import weakref
from pathlib import Path


def _view(dec) -> dict:
    """What the session reads of the decision after a change."""
    return {"last": dec.history[-1], "n": len(dec.history), "tested": list(dec.tested),
            "calibrated": bool(dec.calibrated), "p_label": dec.p_label(), "decision": dec.decision(),
            "p_deficit": dec.p_deficit(), "log_bf": dec.log_bf(), "log_bf_se": dec.log_bf_se()}


def _portable(exc: Exception) -> Exception:
    """``exc`` if it survives pickling, else a RuntimeError with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001
        return RuntimeError(f"{type(exc).__name__}: {exc}")


def main() -> None:
    """The worker (``python -m neckstrength.session.worker``): messages are pickles on stdin / stdout (what the code
    prints to stdout is dropped). The first builds the decision (``("build", args, kwargs, one_blas_thread)``), then
    ``(method, args)`` is answered with ``("ok", view)`` or ``("error", exception)`` until ``None`` or end of input."""
    import contextlib
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)      # an interrupt is the session's to handle (it closes our input)
    out = os.fdopen(os.dup(1), "wb")
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)                                # the solver's banners; warnings and errors still go to stderr
    inp = sys.stdin.buffer

    def send(x):
        try:
            pickle.dump(x, out, protocol=pickle.HIGHEST_PROTOCOL)
            out.flush()
        except (BrokenPipeError, OSError):     # the session is gone
            os._exit(0)

    from neckstrength.sequential.decision import DeficitDecision
    from neckstrength.wrench.batched import single_threaded_blas

    try:
        msg = pickle.load(inp)
    except EOFError:
        return
    _, args, kwargs, one_blas = msg
    with single_threaded_blas() if one_blas else contextlib.nullcontext():
        try:
            dec = DeficitDecision(*args, **kwargs)
            send(("ok", {"history": list(dec.history), "settings": dec.settings, "directions": list(dec.directions),
                         "postures": dec.postures, **_view(dec)}))
        except Exception as exc:  # noqa: BLE001 - sent to the session
            send(("error", _portable(exc)))
            return
        while True:
            try:
                msg = pickle.load(inp)
            except EOFError:
                return
            if msg is None:
                return
            name, a = msg
            try:
                if name == "p_deficit":
                    send(("ok", dec.p_deficit(*a)))
                    continue
                if name not in ("push", "undo"):
                    raise ValueError(f"unknown message {name!r}")
                getattr(dec, name)(*a)
                send(("ok", _view(dec)))
            except Exception as exc:  # noqa: BLE001 - sent to the session
                send(("error", _portable(exc)))


def _stop(proc) -> None:
    try:
        proc.stdin.close()             # end of input: the worker returns
    except Exception:  # noqa: BLE001 - already gone
        pass
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)
    if proc.stdout is not None:
        proc.stdout.close()


class DecisionProcess:
    """A :class:`~neckstrength.sequential.decision.DeficitDecision` in a worker process: started here, built by
    :meth:`build`. :meth:`push` and :meth:`undo` as the decision's; :meth:`push_start` sends a push and returns at once,
    :meth:`push_wait` waits for it (the session updates the joint posterior in between)."""

    def __init__(self):
        # the package's folder first on the worker's path (the same code as this process runs)
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = os.pathsep.join([root] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
        self._proc = subprocess.Popen([sys.executable, "-m", "neckstrength.session.worker"], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, env=env)
        self._finalizer = weakref.finalize(self, _stop, self._proc)
        self._pending = False
        self.history = None

    def build_start(self, args: tuple, kwargs: dict, one_blas_thread: bool = True) -> "DecisionProcess":
        """Send the decision's arguments (``DeficitDecision(*args, **kwargs)``, built in the worker); returns self."""
        self._send(("build", args, kwargs, one_blas_thread))
        return self

    def build_wait(self) -> "DecisionProcess":
        """Wait until the worker built the decision; returns self."""
        first = self._reply()
        self.settings = first["settings"]
        self.directions = first["directions"]
        self.postures = first["postures"]
        self.history = first["history"]
        self._v = first
        return self

    def _send(self, msg) -> None:
        try:
            pickle.dump(msg, self._proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self._proc.stdin.flush()
        except (BrokenPipeError, OSError):
            raise RuntimeError("the deficit decision's worker process stopped") from None

    def _reply(self):
        try:
            kind, val = pickle.load(self._proc.stdout)
        except EOFError:
            raise RuntimeError("the deficit decision's worker process stopped") from None
        if kind == "error":
            raise val
        return val

    def _apply(self, v: dict, push: bool) -> None:
        if push:
            self.history.append(v["last"])
        else:
            self.history.pop()
        assert len(self.history) == v["n"], (len(self.history), v["n"])
        self._v = v

    # -- changes
    def push_start(self, direction: str, force: float, activations=None) -> None:
        if self._pending:
            raise RuntimeError("a push is already under way")
        self._send(("push", (direction, force, activations)))
        self._pending = True

    def push_wait(self) -> None:
        self._pending = False
        self._apply(self._reply(), True)

    def push(self, direction: str, force: float, activations=None) -> None:
        self.push_start(direction, force, activations)
        self.push_wait()

    def undo(self) -> None:
        self._send(("undo", ()))
        self._apply(self._reply(), False)

    def close(self) -> None:
        """Stop the worker (also when this object is collected, or at exit)."""
        self._finalizer()

    # -- what the session reads
    @property
    def tested(self) -> list[str]:
        return list(self._v["tested"])

    @property
    def remaining(self) -> list[str]:
        return [d for d in self.directions if d not in self._v["tested"]]

    @property
    def calibrated(self) -> bool:
        return self._v["calibrated"]

    def p_label(self) -> str:
        return self._v["p_label"]

    def decision(self) -> str:
        return self._v["decision"]

    def p_deficit(self, prevalence: float | None = None) -> float:
        if prevalence is None:
            return self._v["p_deficit"]
        self._send(("p_deficit", (prevalence,)))
        return self._reply()

    def log_bf(self) -> float:
        return self._v["log_bf"]

    def log_bf_se(self) -> float:
        return self._v["log_bf_se"]


if __name__ == "__main__":
    main()
