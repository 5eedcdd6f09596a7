"""The serial/parallel switch shared by every batched kernel (bayeshyst.models._kernels).

The choice between the ``prange`` loop and its serial twin must depend on the size of
the work only, and must never change a bit of the result.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bayeshyst import models
from bayeshyst.models import _kernels as kernels

# every registered model (from the registry, so a new family cannot be missed; effect
# blocks: test_blocks)
FAMILIES = tuple(models.names())


def _record(n: int = 300, fs: float = 5e3) -> SimpleNamespace:
    t = np.arange(n) / fs
    u = 75.0 + 70.0 * np.sin(2 * np.pi * 40 * t) * (0.7 + 0.3 * np.sin(2 * np.pi * 7 * t))
    return SimpleNamespace(t=t, u=u, y=0.12 * u + 0.8 * np.cos(2 * np.pi * 40 * t) + 1.0)


def test_use_parallel_needs_several_walkers_and_enough_work():
    with kernels.kernel_parallelism(100):
        assert not kernels.use_parallel(1, 10**9)  # one walker: nothing to share out
        assert not kernels.use_parallel(4, 99)
        assert kernels.use_parallel(4, 100)
        with kernels.kernel_parallelism(1000):  # the innermost block rules
            assert not kernels.use_parallel(4, 100)
        with kernels.kernel_parallelism(None):  # serial whatever the work
            assert not kernels.use_parallel(4, 10**12)
        assert kernels.use_parallel(4, 100)  # and the outer one is back after it
    # outside every block: the module's default
    assert kernels.use_parallel(4, kernels.PARALLEL_MIN_WORK)
    assert not kernels.use_parallel(4, kernels.PARALLEL_MIN_WORK - 1)
    with pytest.raises(ValueError, match="min_work"):
        with kernels.kernel_parallelism(-5):
            pass


def test_a_busy_check_is_asked_at_every_batch():
    # the diagnosis yields the second core only while a worker holds it: the check is
    # asked per batch, so a fit begun beside a worker goes parallel once it is done
    state = {"busy": True, "asked": 0}

    def busy():
        state["asked"] += 1
        return state["busy"]

    with kernels.kernels_yield_while(busy):
        assert not kernels.use_parallel(8, 10**9)
        state["busy"] = False
        assert kernels.use_parallel(8, 10**9)
        # a batch too small for threads does not ask; a serial block stays serial
        assert not kernels.use_parallel(1, 10**9) and state["asked"] == 2
        with kernels.kernel_parallelism(None):
            assert not kernels.use_parallel(8, 10**9)
    state["busy"] = True
    assert kernels.use_parallel(8, 10**9)  # outside the block the check is gone
    with pytest.raises(ValueError, match="callable"):
        with kernels.kernels_yield_while(True):
            pass


def test_kernel_parallelism_is_per_thread():
    # a serial block in one thread must not change what another thread reads while the
    # block is open (the race of mutating a module global on threaded Dask workers)
    import threading

    inside, seen = threading.Barrier(2), {}

    def serial_fit():
        with kernels.kernel_parallelism(None):
            inside.wait()  # the other thread reads while this block is open
            seen["serial"] = kernels.use_parallel(8, 10**9)
            inside.wait()

    def default_fit():
        inside.wait()
        seen["default"] = kernels.use_parallel(8, 10**9)
        inside.wait()

    threads = [threading.Thread(target=serial_fit), threading.Thread(target=default_fit)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(timeout=30)
    assert seen == {"serial": False, "default": True}


def test_batch_kernel_picks_by_the_size_of_the_work_argument():
    calls = []

    def par(x, out):
        """The parallel loop's doc."""
        calls.append("parallel")
        return "p"

    def ser(x, out):
        calls.append("serial")
        return "s"

    kernel = kernels.batch_kernel(par, ser, work_arg=-1, name="demo_batch")
    assert kernel.__name__ == "demo_batch" and kernel.__doc__ == par.__doc__
    assert kernel.parallel is par and kernel.serial is ser
    with kernels.kernel_parallelism(50):
        assert kernel(None, np.empty((5, 10))) == "p"
        assert kernel(None, np.empty((5, 9))) == "s"
        assert kernel(None, np.empty((1, 10**4))) == "s"
        assert calls == ["parallel", "serial", "serial"]
        heavy = kernels.batch_kernel(par, ser, work_arg=-1, name="heavy_batch", cost=10)
        assert heavy(None, np.empty((5, 1))) == "p"  # 5 entries x 10 units each


@pytest.mark.parametrize("name", FAMILIES)
def test_parallel_and_serial_loops_give_identical_results(name):
    model = models.get(name)
    rec = _record()
    space = model.param_space(rec)
    thetas = space.unpack(space.sample_prior(np.random.default_rng(4), 6))
    runs = []
    for threshold in (0, None):
        with kernels.kernel_parallelism(threshold):
            runs.append(model.run_batch(rec.u, rec.t, thetas))
    par, ser = runs
    np.testing.assert_array_equal(par.failed, ser.failed)
    np.testing.assert_array_equal(par.y, ser.y)
    np.testing.assert_array_equal(par.state, ser.state)
