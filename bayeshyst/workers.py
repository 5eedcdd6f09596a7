"""Process pools for independent pieces of work, one worker per core.

The stages of a study that split into independent tasks (the fits of a model
comparison, the references of a feedforward evaluation) run them in a
:class:`concurrent.futures.ProcessPoolExecutor`: the Python overhead of numerical
inversion and of the samplers' bookkeeping holds the GIL, so threads would not help.
Every worker is set up the same way (:func:`worker_init`):

* numba's kernels run **serially** in it: the pool already uses every core, and a
  worker must never start or enter a numba thread team of its own on cores that the
  other workers hold (serial and parallel loops give the same bits, see
  :mod:`bayeshyst.models._kernels`);
* BLAS runs **single-threaded**: a BLAS team per worker spins on the cores the other
  workers hold (a discrepancy's Gram measured 2-3x slower with the second core busy).

The workers start by ``fork`` where the platform has it: the caller's ``__main__`` is
not imported again (a script without an ``if __name__ == "__main__":`` guard works, as
it always has with the comparison) and a worker costs no start-up. A forked worker
never enters the parent's numba thread team (its kernels are serial) and runs one BLAS
thread, so the parent's thread teams, copied idle, are never used. Elsewhere ``spawn``,
which needs that guard (as every multiprocessing program does).

Examples
--------
>>> from bayeshyst.workers import process_pool
>>> with process_pool(2) as pool:                    # doctest: +SKIP
...     squares = list(pool.map(abs, [-1, -2, -3]))
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from typing import Any

from bayeshyst.errors import ParameterError

__all__ = ["JOBS_ENV", "WorkerTraceback", "default_jobs", "pool_context", "portable",
           "process_pool", "resolve_jobs", "run_forked", "worker_init"]

#: Environment variable that caps the default number of processes (a test runner that
#: already runs one process per core sets it to 1, so pools do not oversubscribe).
JOBS_ENV = "BAYESHYST_JOBS"


def default_jobs() -> int:
    """Cores this process may run on (its CPU affinity where the platform tells it).

    ``BAYESHYST_JOBS`` (:data:`JOBS_ENV`), when set to a whole number >= 1, caps it.

    Raises
    ------
    ParameterError
        If ``BAYESHYST_JOBS`` is set to anything but a whole number >= 1.
    """
    try:
        cores = max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # macOS, Windows: no affinity query
        cores = max(os.cpu_count() or 1, 1)
    text = os.environ.get(JOBS_ENV, "").strip()
    if not text:
        return cores
    if not text.isdigit() or int(text) < 1:
        raise ParameterError(f"environment variable {JOBS_ENV} must be a whole number >= 1, "
                             f"got {text!r}")
    return min(cores, int(text))


def resolve_jobs(n_jobs: int | None, n_tasks: int | None = None) -> int:
    """The number of workers to use: ``n_jobs`` checked, at most one per task.

    Parameters
    ----------
    n_jobs : int or None
        Requested workers; None: one per core (:func:`default_jobs`).
    n_tasks : int, optional
        Number of tasks; no more workers than tasks are started.

    Returns
    -------
    int
        At least 1; 1 means "run in this process".

    Raises
    ------
    ParameterError
        If ``n_jobs`` is not an integer >= 1 (or None).
    """
    if n_jobs is None:
        n = default_jobs()
    elif isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1:
        raise ParameterError(f"n_jobs must be an integer >= 1 or None, got {n_jobs!r}")
    else:
        n = n_jobs
    if n_tasks is not None:
        n = min(n, max(int(n_tasks), 1))
    return n


def worker_init() -> None:
    """Set up a worker process: serial numba kernels and single-threaded BLAS."""
    # imported here: the function runs first thing in a fresh worker
    from threadpoolctl import threadpool_limits

    from bayeshyst.models import serial_kernels_in_this_thread

    serial_kernels_in_this_thread()
    threadpool_limits(1, user_api="blas")


def pool_context(start_method: str | None = None) -> Any:
    """The multiprocessing context the pools start their workers with.

    Parameters
    ----------
    start_method : {"fork", "spawn", "forkserver"}, optional
        Default ``"fork"`` where available, else ``"spawn"`` (module docstring).

    Returns
    -------
    multiprocessing.context.BaseContext

    Raises
    ------
    ParameterError
        For a start method this platform does not offer.
    """
    methods = mp.get_all_start_methods()
    if start_method is None:
        start_method = "fork" if "fork" in methods else "spawn"
    if start_method not in methods:
        raise ParameterError(f"start_method must be one of {methods} here, got "
                             f"{start_method!r}")
    return mp.get_context(start_method)


@contextmanager
def process_pool(n_jobs: int, *, start_method: str | None = None
                 ) -> Iterator[ProcessPoolExecutor]:
    """A process pool of ``n_jobs`` workers set up by :func:`worker_init`.

    Parameters
    ----------
    n_jobs : int
        Number of worker processes (>= 1; :func:`resolve_jobs` picks one).
    start_method : str, optional
        As :func:`pool_context`.

    Yields
    ------
    concurrent.futures.ProcessPoolExecutor
        Shut down (waiting for its tasks) when the block ends; submit module-level
        functions with picklable arguments. ``pool.map`` returns results in the order
        of its inputs.

    Raises
    ------
    ParameterError
        If ``n_jobs`` is not an integer >= 1.
    """
    if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < 1:
        raise ParameterError(f"n_jobs must be an integer >= 1, got {n_jobs!r}")
    with ProcessPoolExecutor(max_workers=n_jobs, mp_context=pool_context(start_method),
                             initializer=worker_init) as pool:
        yield pool


class WorkerTraceback(Exception):
    """The traceback of an exception raised in a worker, chained to it as its cause."""

    def __str__(self) -> str:
        return "\n\n" + str(self.args[0]) if self.args else ""


def portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError naming it (its text kept)."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # any failure of a foreign exception's pickling
        return RuntimeError(f"{type(exc).__name__}: {exc}")


def _run_share(fn: Callable[[Any], object], items: Sequence[Any], share: Sequence[int],
               conn: Any) -> None:
    """A forked child of :func:`run_forked`: its share of the items, then what failed."""
    worker_init()
    failed = []
    for i in share:
        try:
            fn(items[i])
        except Exception as exc:  # sent to the parent, which raises it
            failed.append((i, portable(exc), traceback.format_exc()))
    conn.send(failed)
    conn.close()


def run_forked(fn: Callable[[Any], object], items: Sequence[Any],
               n_jobs: int | None = None) -> None:
    """``fn(item)`` for every item, shared between this process and forked children.

    For work whose inputs live in this process's memory and are costly or impossible to
    pickle (matplotlib figures to save): a child started by ``fork`` sees them as they
    are, and only a failure travels back. ``fn`` acts by side effect (writes a file);
    what it returns is dropped. With ``n`` processes, child ``j`` takes the items
    ``j, j + n, ...`` (``j >= 1``) and this process the others. Without ``fork`` on this
    platform, or with one process, every item runs here, in order.

    Parameters
    ----------
    fn : callable
        Called once per item.
    items : sequence
        The items.
    n_jobs : int or None
        Processes, this one included (:func:`resolve_jobs`: None is one per core; never
        more than items).

    Raises
    ------
    Exception
        The exception of the first item (in item order) whose ``fn`` raised, wherever
        it ran (from a child: chained to its :class:`WorkerTraceback`), after every
        process has finished its share.
    RuntimeError
        If a child died before reporting (its items named).
    """
    n = resolve_jobs(n_jobs, len(items))
    if n == 1 or "fork" not in mp.get_all_start_methods():
        for item in items:
            fn(item)
        return
    ctx = mp.get_context("fork")
    children = []
    for j in range(1, n):
        recv, send = ctx.Pipe(duplex=False)
        share = list(range(j, len(items), n))
        proc = ctx.Process(target=_run_share, args=(fn, items, share, send), daemon=True)
        proc.start()
        send.close()  # so that a child's death reads as EOF here
        children.append((proc, recv, share))
    failed: list[tuple[int, BaseException, str]] = []
    for i in range(0, len(items), n):
        try:
            fn(items[i])
        except Exception as exc:  # raised below, in item order, once the children end
            failed.append((i, exc, ""))
    for proc, recv, share in children:
        try:
            failed += recv.recv()
        except EOFError:
            proc.join()
            failed.append((share[0], RuntimeError(
                f"a forked worker died (exit code {proc.exitcode}) before reporting on "
                f"items {share}"), ""))
        recv.close()
        proc.join()
    if failed:
        _, exc, tb = min(failed, key=lambda f: f[0])
        raise exc from (WorkerTraceback(tb) if tb else None)
