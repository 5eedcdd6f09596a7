"""Simulation speed of every registered model: numba kernel vs the same code interpreted.

For each model (default settings, parameters at the prior mean of a data-scaled space)
it times, in one run:

* the compiled kernel, one parameter vector, N = 10^4 and 10^5 samples (best of R);
* the same kernel with numba disabled (``NUMBA_DISABLE_JIT=1`` in a subprocess, so the
  interpreted Python of the very same loop is measured) on a shorter record;
* a batch of W = 32 parameter vectors (what one emcee step evaluates), parallel over
  walkers on the machine's cores.

It prints ns per sample, ns per operator-sample for operator models, and the ratio
interpreted / compiled. ``--write`` replaces the table in ``benchmarks/RESULTS.md``.

Usage::

    python benchmarks/bench_kernels.py [--quick] [--write] [--models pi_play,bouc_wen]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _signal(n: int, fs: float = 1e3) -> tuple[np.ndarray, np.ndarray]:
    # a 10 Hz sine with a slow amplitude modulation: nested loops and reversals at every
    # scale, the worst case for memory-keeping operators; fs = 1 kHz gives 100 samples
    # per period (coarse: adaptive integrators take extra sub-steps), 10 kHz gives 1000
    t = np.arange(n) / fs
    u = 75.0 + 70.0 * np.sin(2 * np.pi * 10 * t) * (0.6 + 0.4 * np.sin(2 * np.pi * 0.37 * t))
    return u, t


def _setup(name: str):
    from bayeshyst import models
    from bayeshyst.models.base import DataScales

    model = models.get(name)
    scales = DataScales(0.0, 150.0, -1.0, 20.0)
    space = model.param_space(scales)
    # the prior mean in z is a typical, valid parameter vector for every model
    z = np.mean(space.sample_prior(np.random.default_rng(0), 400), axis=0)
    return model, space, z


def _operators(model) -> int:
    for attr in ("n_operators", "n_elements"):
        if hasattr(model, attr):
            return int(getattr(model, attr))
    return 0


def _time(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def measure(name: str, sizes: list[int], repeats: int, batch: int, fs: float = 1e3) -> dict:
    """Time one model compiled (all sizes, and a batch) in this process."""
    model, space, z = _setup(name)
    theta = space.unpack(z)
    label = name if fs == 1e3 else f"{name} ({fs / 10:.0f} samples/period)"
    out = {"model": label, "operators": _operators(model), "ns_per_sample": {}}
    u, t = _signal(16, fs)
    model.simulate(u, t, theta)  # compile outside the timing
    for n in sizes:
        u, t = _signal(n, fs)
        sec = _time(lambda u=u, t=t: model.simulate(u, t, theta), repeats)
        out["ns_per_sample"][str(n)] = sec / n * 1e9
    # the batch: prior draws inside the model's valid region (as an ensemble would be)
    u, t = _signal(sizes[0], fs)
    draws = space.sample_prior(np.random.default_rng(1), 8 * batch)
    ok = ~model.run_batch(u, t, space.unpack(draws)).failed
    thetas = space.unpack(draws[ok][:batch])
    model.simulate_batch(u, t, thetas)
    sec = _time(lambda: model.simulate_batch(u, t, thetas), repeats)
    out["batch_ns_per_walker_sample"] = sec / (batch * sizes[0]) * 1e9
    return out


def measure_interpreted(name: str, n: int, fs: float = 1e3) -> float:
    """ns per sample of the same kernel with numba disabled, in a subprocess."""
    code = (
        f"import json,sys,time;sys.path.insert(0,{str(ROOT)!r});"
        "from benchmarks.bench_kernels import _setup,_signal;"
        f"m,s,z=_setup({name!r});th=s.unpack(z);u,t=_signal({n},{fs});"
        "t0=time.perf_counter();m.simulate(u,t,th);"
        f"print(json.dumps((time.perf_counter()-t0)/{n}*1e9))"
    )
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True, cwd=ROOT)
    return float(json.loads(res.stdout.strip().splitlines()[-1]))


def table(rows: list[dict], sizes: list[int]) -> str:
    head = ["model"] + [f"ns/sample N={n:.0e}" for n in sizes] + [
        "ns/operator-sample (largest N)", "ns/walker-sample (W=32)", "interpreted ns/sample",
        "speed-up"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        big = r["ns_per_sample"][str(sizes[-1])]
        per_op = f"{big / r['operators']:.2f}" if r["operators"] else "–"
        cells = [r["model"]] + [f"{r['ns_per_sample'][str(n)]:.1f}" for n in sizes] + [
            per_op, f"{r['batch_ns_per_walker_sample']:.1f}", f"{r['interpreted']:.0f}",
            f"{r['interpreted'] / big:.0f}x"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes, one repeat")
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    ap.add_argument("--models", default="", help="comma-separated names (default: all)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from bayeshyst import models
    from benchmarks._results import write_section

    names = [n for n in args.models.split(",") if n] or models.names()
    load_start = os.getloadavg()[0]
    sizes = [1_000, 10_000] if args.quick else [10_000, 100_000]
    repeats = 1 if args.quick else 5
    n_interp = 300 if args.quick else 2_000
    rows = []
    # the differential models also at 1000 samples per period, where their adaptive
    # sub-stepping settles to about one step per sample
    fine = [n for n in ("bouc_wen", "bouc_wen_asym", "duhem") if n in names]
    for name, fs in [(n, 1e3) for n in names] + [(n, 1e4) for n in fine]:
        r = measure(name, sizes, repeats, batch=32, fs=fs)
        r["interpreted"] = measure_interpreted(name, n_interp, fs)
        rows.append(r)
        print(f"{r['model']:<40} {r['ns_per_sample'][str(sizes[-1])]:9.1f} ns/sample  "
              f"interpreted {r['interpreted']:10.0f} ns/sample  "
              f"ratio {r['interpreted'] / r['ns_per_sample'][str(sizes[-1])]:8.0f}x",
              flush=True)
    text = table(rows, sizes)
    print()
    print(text)
    if args.write:
        import numba

        meta = (f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, "
                f"{os.cpu_count()} cores, Python {platform.python_version()}, "
                f"numpy {np.__version__}, numba {numba.__version__}; load average "
                f"{load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end. "
                "Interpreted = the same kernels with NUMBA_DISABLE_JIT=1, "
                f"N = {n_interp}.")
        write_section("kernels", "Kernel simulation speed", f"{meta}\n\n{text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
