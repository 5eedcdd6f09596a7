"""numba-jitted time loops, one module per model family, and their serial/parallel switch.

DESIGN.md names a single ``_kernels.py``; it is a package here so that each family's
loops stay in a small module of their own (operators, Preisach, differential models,
effect blocks) and can be developed and benchmarked independently.
Kernels take C-contiguous float64 arrays, write into preallocated outputs and never
allocate per sample.

Serial or parallel
------------------
Every batched kernel is written once, as a per-walker function (``_pi_play_one``,
``staircase_one``, ...) that simulates one parameter vector. Two loops over the walkers
call it: ``_<name>_par``, compiled with ``parallel=True`` (``prange``), and
``_<name>_ser``, a plain ``range`` loop that never touches numba's thread pool.
:func:`batch_kernel` joins the pair into the public ``<name>`` that callers use, and
:func:`use_parallel` picks one per call from the size of the work. Walkers are
independent, so the choice changes the speed only, never a bit of the result.

The twins are two Python functions on purpose: numba's on-disk cache keys an entry by
the function's name, line and signature, not by its compile flags, so one function
compiled both ways would share a single cache entry and the serial twin would load the
parallel code.
"""

from __future__ import annotations

import contextvars
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["PARALLEL_MIN_WORK", "batch_kernel", "kernel_parallelism", "kernels_yield_while",
           "serial_kernels_in_this_thread", "use_parallel"]

#: Work (walkers x samples, or walkers x table entries, times the kernel's ``cost``)
#: below which a batch runs serially. Starting numba's thread team for one ``prange``
#: loop takes a few microseconds when a core is idle, but a scheduler slice when the
#: cores are busy: 4-8 ms measured on a loaded 2-core machine, more than a single
#: walker, the one-sample steps of numerical inversion or a short record cost in all.
#: At 20 000 walker-samples the serial loops take about 0.1-3 ms (3-130 ns per
#: walker-sample for every kernel but MRC, which declares ``cost=100``), so below it
#: threads could save at most half of that on two cores and can lose several ms; an
#: emcee step (32 walkers x a record of 10^3 samples or more) is above it.
PARALLEL_MIN_WORK = 20_000

# the threshold in force in this thread (and asyncio task): a context variable, not a
# module global, so a Dask worker's threads or a process pool's initialiser each set
# their own without racing on a value another fit is reading
_MIN_WORK: contextvars.ContextVar[int | None] = contextvars.ContextVar(
    "bayeshyst_parallel_min_work", default=None)
# while this says another process holds a core, batches run serially (see
# kernels_yield_while); a context variable for the same reason
_BUSY: contextvars.ContextVar[Callable[[], bool] | None] = contextvars.ContextVar(
    "bayeshyst_kernels_yield_while", default=None)


@contextmanager
def kernel_parallelism(min_work: int | None = PARALLEL_MIN_WORK) -> Iterator[None]:
    """Within the block, in this thread only, run batches of at least ``min_work`` on
    numba's thread team; ``None`` runs every batch serially.

    Parameters
    ----------
    min_work : int or None
        Walkers x samples (times the kernel's cost) from which a batch goes parallel;
        None: never (a process or thread pool already uses every core).

    Examples
    --------
    >>> with kernel_parallelism(None):   # one fit per core in a pool: serial kernels
    ...     pass
    """
    if min_work is not None and (isinstance(min_work, bool) or not isinstance(min_work, int)
                                 or min_work < 0):
        raise ValueError(f"kernel_parallelism: min_work must be a non-negative int or None, "
                         f"got {min_work!r}")
    token = _MIN_WORK.set(-1 if min_work is None else min_work)
    try:
        yield
    finally:
        _MIN_WORK.reset(token)


@contextmanager
def kernels_yield_while(busy: Callable[[], bool]) -> Iterator[None]:
    """Within the block, in this thread only, run a batch serially whenever ``busy()``.

    ``busy`` is asked at every batch that would go parallel: a process that shares the
    cores with workers of its own (the diagnosis' prefetched fits) yields the second
    core while one of them runs and takes it back as soon as none does, not only at
    the next fit. The result is the same either way, to the bit.

    Parameters
    ----------
    busy : callable () -> bool
        Whether another process holds a core now; cheap (it is asked per batch, a few
        hundred times a second).
    """
    if not callable(busy):
        raise ValueError(f"kernels_yield_while: busy must be callable, got {busy!r}")
    token = _BUSY.set(busy)
    try:
        yield
    finally:
        _BUSY.reset(token)


def serial_kernels_in_this_thread() -> None:
    """Make every batch of this thread serial for the rest of its life (a pool worker's
    initialiser: the pool already uses every core, and a forked child must never enter
    the parent's numba thread pool)."""
    _MIN_WORK.set(-1)


def use_parallel(walkers: int, work: int) -> bool:
    """Whether a batch is worth numba's thread team.

    Parameters
    ----------
    walkers : int
        Number of independent parameter vectors (the ``prange`` axis).
    work : int
        Total work, ``walkers`` times the per-walker loop length (samples, or table
        entries for the Everett tables).

    Returns
    -------
    bool
        True for more than one walker and ``work`` at least the threshold in force
        (that of the innermost :func:`kernel_parallelism` block of this thread, else
        :data:`PARALLEL_MIN_WORK`), unless a :func:`kernels_yield_while` block of this
        thread says another process holds a core.
    """
    threshold = _MIN_WORK.get()
    if threshold is None:
        threshold = PARALLEL_MIN_WORK
    if not (walkers > 1 and threshold >= 0 and work >= threshold):
        return False
    busy = _BUSY.get()
    return busy is None or not busy()


def batch_kernel(parallel: Callable[..., Any], serial: Callable[..., Any], *,
                 work_arg: int, name: str, cost: int = 1) -> Callable[..., Any]:
    """One batched kernel from its ``prange`` loop and its serial twin.

    Parameters
    ----------
    parallel, serial : numba dispatcher
        The same loop over walkers, compiled with and without ``parallel=True``, with
        the same signature.
    work_arg : int
        Position (negative counts from the end) of an argument whose shape is
        ``(W, *per_walker)``, usually the output: its leading axis gives the walkers
        and its size, times ``cost``, the work passed to :func:`use_parallel`.
    name : str
        Public name of the kernel (for ``repr`` and docs).
    cost : int
        Work units per entry of that argument: 1 for the kernels that take a few to a
        hundred nanoseconds per walker-sample, more for much heavier ones.

    Returns
    -------
    callable
        ``kernel(*args)`` runs ``parallel(*args)`` or ``serial(*args)`` and returns its
        result; ``kernel.parallel`` and ``kernel.serial`` give the two loops. The
        docstring is the parallel loop's.
    """

    def kernel(*args: Any) -> Any:
        shaped = args[work_arg]
        run = parallel if use_parallel(shaped.shape[0], shaped.size * cost) else serial
        return run(*args)

    kernel.__name__ = kernel.__qualname__ = name
    kernel.__module__ = getattr(parallel, "__module__", __name__)
    kernel.__doc__ = parallel.__doc__
    kernel.parallel = parallel  # type: ignore[attr-defined]
    kernel.serial = serial  # type: ignore[attr-defined]
    return kernel
