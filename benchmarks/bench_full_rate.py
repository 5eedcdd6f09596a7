"""A 10 kHz, 40 000-sample record diagnosed as a user runs it: ``bayeshyst diagnose``.

Issue 59's target: a record at its full rate, one effect hidden in it, diagnosed in at
most 5 minutes on 2 cores, without a decimation flag. Three records of a 3-operator play
PI (p0 0.12, weights 0.05, 0.03, 0.02) under a 5 Hz sine, 20 cycles at 10 kHz, white
noise 0.2 % of the stroke, each with two covariate columns:

* ``temperature_gain``: the gain follows ``temperature_c`` (+0.6 %/K over a 9 K
  half-sine), ``load_n`` irrelevant. Right: ``aux`` on ``temperature_c`` kept, and only
  that.
* ``change_point``: gain -2.5 % and offset +0.05 um from 2.6 s on (not declared).
  Right: ``change_point`` kept, and only that.
* ``clean``: nothing hidden, both columns irrelevant. Right: nothing kept.

Each is diagnosed by the command line (``--model "pi_play(n_operators=3)"``, defaults
otherwise: working rate ``auto``, every candidate effect), in a subprocess, timed by the
wall clock. The baseline, in the same run: one posterior fit of the base model to the
first record at its full rate (what every fit of a diagnosis cost before the working
rate), so the ratio says what the whole diagnosis costs in units of that one fit.

Usage::

    python benchmarks/bench_full_rate.py [--write]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FS = 10_000.0  # Hz
F_EXC = 5.0  # Hz
CYCLES = 20
BASE = "pi_play(n_operators=3)"
#: what each case must keep (the effect names of summary.json's effects_found)
EXPECTED = {"temperature_gain": ["aux"], "change_point": ["change_point"], "clean": []}


def _pi(t: np.ndarray, u: np.ndarray) -> np.ndarray:
    from bayeshyst.data import Record
    from bayeshyst.models import get as get_model

    model = get_model(BASE)
    theta = {**model.param_space(Record(t=t, u=u, y=u.copy())).fixed, "p0": 0.12,
             "w": np.array([0.05, 0.03, 0.02])}
    return model.simulate(u, t, theta)


def write_cases(folder: Path, seed: int = 5) -> dict[str, Path]:
    """The three records as CSV files in ``folder`` (columns t, u, y, temperature_c, load_n)."""
    rng = np.random.default_rng(seed)
    t = np.arange(round(CYCLES * FS / F_EXC) + 1) / FS
    u = 10.0 * np.sin(2 * np.pi * F_EXC * t)
    y0 = _pi(t, u)
    temp = 20.0 + 9.0 * np.sin(np.pi * t / t[-1])
    after = t >= 2.6
    ys = {"temperature_gain": y0 * (1.0 + 0.006 * (temp - temp.mean())),
          "change_point": np.where(after, 0.975 * y0 + 0.05, y0),
          "clean": y0}
    out = {}
    for name, y in ys.items():
        y = y + 0.002 * np.ptp(y0) * rng.standard_normal(t.size)
        load = 5.0 + rng.standard_normal(t.size)
        tc = temp if name == "temperature_gain" else 20.0 + rng.standard_normal(t.size)
        path = folder / f"{name}.csv"
        np.savetxt(path, np.column_stack([t, u, y, tc, load]), delimiter=",",
                   header="t,u,y,temperature_c,load_n", comments="", fmt="%.9g")
        out[name] = path
    return out


def diagnose(path: Path, out: Path) -> tuple[float, dict]:
    """Wall time of ``bayeshyst diagnose`` on ``path`` and its summary."""
    cmd = [sys.executable, "-m", "bayeshyst.cli", "diagnose", str(path), "--model", BASE,
           "--out", str(out), "--quiet", "--no-figures"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    return wall, json.loads((out / "summary.json").read_text())


def base_fit_full_rate(path: Path) -> float:
    """Wall time of one posterior fit of the base model to ``path`` at its full rate."""
    from bayeshyst.data import load
    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.models import get as get_model

    data = load(path)
    t0 = time.perf_counter()
    res = sample_posterior(Posterior(data, get_model(BASE), "gaussian"))
    wall = time.perf_counter() - t0
    if not res.converged:
        print("warning: the baseline fit did not converge")
    return wall


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="write to benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    load_avg = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cases = write_cases(Path(tmp))
        base = base_fit_full_rate(cases["temperature_gain"])
        for name, path in cases.items():
            wall, summary = diagnose(path, Path(tmp) / f"out_{name}")
            found = sorted(e.split("(")[0] for e in summary["effects_found"])
            rate = summary.get("working_rate") or {}
            recs = rate.get("records") or [{}]
            rows.append((name, wall, found, found == sorted(EXPECTED[name]),
                         recs[0].get("fs_out_hz"), summary["after"]["rmse"]))
    lines = [f"Machine: {platform.machine()}, {os.cpu_count()} cores, Python "
             f"{platform.python_version()}; load average {load_avg:.2f} at the start.",
             "",
             f"Baseline, same run: one fit of `{BASE}` to `temperature_gain` at its full "
             f"10 kHz (40 001 samples): {base:.1f} s.",
             "",
             "| record | diagnose wall | / baseline fit | working rate | effects kept | "
             "right | RMSE after |",
             "|---|---|---|---|---|---|---|"]
    for name, wall, found, ok, fs_out, rmse in rows:
        lines.append(f"| {name} | {wall:.1f} s | {wall / base:.2f} | "
                     f"{fs_out:g} Hz | {', '.join(found) or 'none'} | "
                     f"{'yes' if ok else 'NO'} | {rmse:.4g} |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("full_rate", "A 10 kHz record diagnosed at its full rate "
                      "(bench_full_rate.py)", text)
    return 0 if all(r[3] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
