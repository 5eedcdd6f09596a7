"""Thread teams on shared cores: single-threaded BLAS where numba's kernels run.

The sampler alternates numba's parallel simulation kernels (one thread per core) with
small BLAS products (Grams, a discrepancy's basis times its coefficients, Cholesky
factors of ~100 x 100). OpenBLAS's team spins after each call and then competes with
numba's threads for the same cores: measured on 2 cores, one log-density batch of 24
Bouc–Wen walkers with a discrepancy took 11.1 ms with OpenBLAS's two threads and 5.8 ms
with one (5.3 and 4.7 ms without the discrepancy); 64 ``pi_play(8)`` walkers with a
discrepancy 41.6 ms against 3.3 ms. Products this small gain nothing from a second BLAS
thread, so the inference's entry points (the fits, the MAP search, the sampler on a
hysteresis posterior) and the posterior's batch evaluations run with one
(:func:`with_single_threaded_blas`); other work (a GP's hyperparameters over a large
training set, whose Cholesky factors do gain from threads) keeps the configured team.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from threadpoolctl import ThreadpoolController

__all__ = ["single_threaded_blas", "with_single_threaded_blas"]

_F = TypeVar("_F", bound=Callable[..., Any])


@functools.cache
def _controller() -> ThreadpoolController:
    # built on first use and kept: it inspects the loaded libraries (milliseconds)
    return ThreadpoolController()


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """One BLAS thread inside the block; the previous count restored after it (nests)."""
    with _controller().limit(limits=1, user_api="blas"):
        yield


def with_single_threaded_blas(func: _F) -> _F:
    """Decorate ``func`` to run under :func:`single_threaded_blas`."""
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with single_threaded_blas():
            return func(*args, **kwargs)
    return wrapper  # type: ignore[return-value]
