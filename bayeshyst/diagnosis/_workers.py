"""Speculative fits of the diagnosis loop in worker processes.

The loop (:mod:`bayeshyst.diagnosis.loop`) decides serially: it fits a candidate, gates
it, and only then knows whether it needs the next one. Every fit's seed and checkpoint
follow from what is fitted (:func:`~bayeshyst.selection.tasks.fit_sampler`), so a fit
gives the same result whenever and wherever it runs. The loop therefore fits what it
needs now in its own process and hands the fits it *may* need next to a
:class:`Prefetcher`, whose workers run them meanwhile; when the loop reaches one it
takes the result, and the fits it never reaches are discarded -- a worker still running
one is ended, so that a guess that lost does not hold a core the next round needs.
Ending a sampler at any instant is safe: its checkpoint is written to survive it
(:mod:`bayeshyst.inference.checkpoint`).

Workers are started as :mod:`bayeshyst.workers` starts every pool (``fork`` where the
platform has it, so a script needs no ``if __name__ == "__main__":`` guard; else
``spawn``), run their kernels serially and BLAS on one thread
(:func:`~bayeshyst.workers.worker_init`), and live until the diagnosis ends or their
fit is discarded. A fit function that cannot be pickled by name (a test's stand-in
defined inside a function) cannot be shipped: the prefetcher then stays off and every
fit runs in the caller.

Private to :mod:`bayeshyst.diagnosis`; a public pool for every command may replace it.
"""

from __future__ import annotations

import contextlib
import logging
import pickle
import traceback
from collections.abc import Callable, Hashable, Iterator
from multiprocessing.connection import Connection, wait
from typing import Any

from bayeshyst.models import kernels_yield_while
from bayeshyst.workers import WorkerTraceback, pool_context, portable, worker_init

__all__ = ["Prefetcher", "WorkerTraceback", "can_ship"]

_log = logging.getLogger(__name__)


def can_ship(fn: Callable[..., Any]) -> bool:
    """Whether ``fn`` reaches a worker: it pickles by name and names itself."""
    try:
        return pickle.loads(pickle.dumps(fn)) is fn
    except (pickle.PicklingError, AttributeError, TypeError, ImportError):
        return False


def _serve(conn: Connection) -> None:
    """A worker: run ``(tag, fn, args)`` messages one at a time, send ``(tag, ok, value, tb)``.

    Returns when the caller closes its end or sends None.
    """
    worker_init()
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        tag, fn, args = msg
        try:
            out = (tag, True, fn(*args), "")
        except Exception as exc:  # sent to the caller, who raises it
            out = (tag, False, portable(exc), traceback.format_exc())
        try:
            conn.send(out)  # pickled whole before a byte is written
        except (pickle.PicklingError, TypeError, AttributeError) as exc:
            conn.send((tag, False, RuntimeError(f"the worker's result cannot be sent back: "
                                                f"{exc}"), traceback.format_exc()))


class _Worker:
    """One worker process and the caller's end of its pipe; ``tag``: its fit, if any."""

    def __init__(self, ctx: Any) -> None:
        self.conn, child = ctx.Pipe()
        # not daemonic: a fit may start processes of its own (daemons may not)
        self.proc = ctx.Process(target=_serve, args=(child,), name="bayeshyst-diagnosis")
        self.proc.start()
        child.close()  # so that the worker's death reads as EOF here
        self.tag: int | None = None

    def stop(self, kill: bool) -> None:
        """End the worker: at once (``kill``, its fit is not wanted) or after its loop."""
        if kill:
            self.proc.terminate()
        else:
            with contextlib.suppress(OSError):
                self.conn.send(None)
        self.proc.join()
        self.conn.close()


class Prefetcher:
    """Fits submitted ahead of need, run in up to ``n_workers`` worker processes.

    Parameters
    ----------
    n_workers : int
        Worker processes (0: off, every :meth:`submit` is ignored).
    fn : callable
        What a worker runs, ``fn(*args)``; it must be importable by name
        (:func:`can_ship`), else the prefetcher is off.
    context : multiprocessing context, optional
        Default :func:`pool_context`.

    Use as a context manager: leaving it ends every worker, discarding what they run.
    Tasks wait in submission order for a free worker; workers start on first need.
    """

    def __init__(self, n_workers: int, fn: Callable[..., Any], context: Any = None) -> None:
        self.fn = fn
        self.n_workers = int(n_workers) if can_ship(fn) else 0
        self._ctx = pool_context() if context is None else context
        self._workers: list[_Worker] = []
        self._tags: dict[Hashable, int] = {}  # key -> tag of a pending task
        self._queue: list[tuple[int, tuple[Any, ...]]] = []  # (tag, args) not started
        self._done: dict[int, tuple[bool, Any, str]] = {}  # tag -> (ok, value, traceback)
        self._next = 0

    @property
    def enabled(self) -> bool:
        """Whether submitted fits run in workers."""
        return self.n_workers > 0

    @property
    def pending(self) -> int:
        """Tasks submitted and neither taken nor discarded."""
        return len(self._tags)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._tags

    def __enter__(self) -> Prefetcher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def submit(self, key: Hashable, *args: Any) -> None:
        """Run ``fn(*args)`` ahead of need under ``key`` (ignored if off or already there)."""
        if not self.enabled or key in self._tags:
            return
        tag, self._next = self._next, self._next + 1
        self._tags[key] = tag
        self._queue.append((tag, args))
        self._dispatch()

    def take(self, key: Hashable) -> Any:
        """The result under ``key``, waiting for it; the worker's exception is raised here.

        Raises
        ------
        KeyError
            If nothing is pending under ``key``.
        """
        tag = self._tags.pop(key)
        if any(t == tag for t, _ in self._queue):
            # not started: the caller, idle until it has it, runs it itself
            args = next(a for t, a in self._queue if t == tag)
            self._queue = [(t, a) for t, a in self._queue if t != tag]
            with self.sharing():
                return self.fn(*args)
        while tag not in self._done:
            self._collect(block=True)
        ok, value, tb = self._done.pop(tag)
        if ok:
            return value
        raise value from (WorkerTraceback(tb) if tb else None)

    def discard(self) -> None:
        """Forget every pending task; a worker running one is ended (it is not wanted)."""
        self._tags.clear()
        self._queue.clear()
        self._done.clear()
        for w in [w for w in self._workers if w.tag is not None]:
            w.stop(kill=True)
            self._workers.remove(w)

    def running(self) -> bool:
        """Whether a worker is fitting now: it has a task and has not sent its result.

        Reads no result and dispatches nothing (a poll of each running worker's pipe):
        cheap enough to be asked at every kernel batch.
        """
        return any(w.tag is not None and w.proc.is_alive() and not w.conn.poll()
                   for w in self._workers)

    @contextlib.contextmanager
    def sharing(self) -> Iterator[None]:
        """Serial kernels in the caller whenever a worker holds a core, parallel otherwise.

        Asked at every kernel batch (:func:`~bayeshyst.models.kernels_yield_while`):
        decided once at the start of a fit, a fit begun beside a speculative one ran on
        one core to its end, long after the worker had finished (the 150 V piezo's
        refits: load 1.1 on 2 cores for minutes). Serial or parallel, a kernel's result
        is the same to the bit (:mod:`bayeshyst.models._kernels`). BLAS runs one thread
        in every diagnosis fit anyway (:func:`~bayeshyst.diagnosis._fitting.diagnosis_fit`):
        a reduction split over another number of threads may round differently.
        """
        with kernels_yield_while(self.running):
            yield

    def close(self) -> None:
        """End every worker: running ones at once, idle ones after their loop."""
        self._tags.clear()
        self._queue.clear()
        self._done.clear()
        for w in self._workers:
            w.stop(kill=w.tag is not None)
        self._workers.clear()

    # ------------------------------------------------------------------ internals
    def _dispatch(self) -> None:
        """Start queued tasks on idle workers, starting workers up to ``n_workers``.

        A worker that cannot be started or reached (under ``spawn``, a script without
        the ``if __name__ == "__main__":`` guard) turns the prefetcher off: what is
        queued, and everything after, is fitted by the caller when needed.
        """
        while self._queue and self.n_workers:
            idle = [w for w in self._workers if w.tag is None]
            try:
                if not idle and len(self._workers) < self.n_workers:
                    idle = [_Worker(self._ctx)]
                    self._workers.append(idle[0])
                if not idle:
                    return
                idle[0].conn.send((self._queue[0][0], self.fn, self._queue[0][1]))
            except (pickle.PicklingError, TypeError, AttributeError) as exc:
                # pickled whole before a byte is sent: the pipe is clean, and the caller
                # fits what cannot travel when it needs it
                tag = self._queue.pop(0)[0]
                self._tags = {k: t for k, t in self._tags.items() if t != tag}
                _log.warning("a diagnosis fit cannot be sent to a worker (%s): it is "
                             "fitted in this process when needed", exc)
                continue
            except (OSError, RuntimeError, EOFError) as exc:
                _log.warning("diagnosis workers unavailable (%s): fitting in this process",
                             exc)
                self.n_workers = 0
                for w in [w for w in self._workers if w.tag is None]:
                    w.stop(kill=True)
                    self._workers.remove(w)
                return
            idle[0].tag = self._queue.pop(0)[0]

    def _collect(self, block: bool) -> None:
        """Receive finished results (waiting for one when ``block``), then dispatch."""
        running = [w for w in self._workers if w.tag is not None]
        if not running:
            return
        ready = wait([w.conn for w in running] + [w.proc.sentinel for w in running],
                     timeout=None if block else 0)
        for w in running:
            if w.conn in ready:
                try:
                    tag, ok, value, tb = w.conn.recv()
                except (EOFError, OSError) as exc:
                    tag, ok, value, tb = w.tag, False, RuntimeError(
                        f"a diagnosis worker died while fitting (exit code "
                        f"{w.proc.exitcode}): {exc!r}"), ""
                except Exception as exc:  # a result that cannot be unpickled
                    tag, ok, value, tb = w.tag, False, RuntimeError(
                        f"a diagnosis worker's result cannot be read: {exc!r}"), ""
                self._done[tag] = (ok, value, tb)
                w.tag = None
            elif w.proc.sentinel in ready:
                w.proc.join()
                self._done[w.tag] = (False, RuntimeError(
                    f"a diagnosis worker died while fitting (exit code {w.proc.exitcode})"),
                    "")
                w.tag = None
            if w.tag is None and not w.proc.is_alive():
                w.stop(kill=False)
                self._workers.remove(w)
        self._dispatch()
