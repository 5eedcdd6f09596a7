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

from collections.abc import Callable
from typing import Any

__all__ = ["PARALLEL_MIN_WORK", "batch_kernel", "use_parallel"]

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
        True for more than one walker and ``work >= PARALLEL_MIN_WORK`` (read at call
        time, so it can be changed at run time or in tests).
    """
    return walkers > 1 and work >= PARALLEL_MIN_WORK


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
