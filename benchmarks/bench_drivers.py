"""The cost of looking beyond the catalogue: the driver scan and the spectral lines.

Every residual of a diagnosis is now also scanned for dependence on anything observed
(:func:`bayeshyst.diagnosis.drivers.scan_drivers`, 999 sign patterns) and for spectral
lines (:func:`bayeshyst.diagnosis.spectrum.spectral_lines`). The baseline, measured in
the same run on the same data, is the residual analysis without them
(``analyse_residual(..., n_permutations=0)``: the catalogue's score tests, the fit's
sensitivities, the AR whitening). Data: the bundled virtual actuator (5 frequencies)
with a temperature column added (two covariates: one that drives the gain, one
irrelevant), fitted with a short ``pi_play(n_operators=8)`` run.

Usage::

    python benchmarks/bench_drivers.py [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._results import median_time  # noqa: E402  (after the path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = parser.parse_args()
    from bayeshyst.data import Dataset, load
    from bayeshyst.demo import bundled_data
    from bayeshyst.diagnosis import analyse_residual
    from bayeshyst.inference.posterior import Posterior
    from bayeshyst.inference.sampling import sample_posterior
    from bayeshyst.inference.settings import SamplerSettings

    raw = load(bundled_data())
    rng = np.random.default_rng(0)
    records = []
    for rec in raw:
        temp = 20.0 + 5.0 * np.sin(np.pi * (rec.t - rec.t[0]) / np.ptp(rec.t))
        y = rec.y * (1.0 + 0.004 * (temp - temp.mean()))
        records.append(rec.with_(y=y, covariates={"temperature_c": temp,
                                                  "load_n": rng.standard_normal(rec.n)}))
    data = Dataset(tuple(records), name="virtual+temperature")
    post = Posterior(data, "pi_play(n_operators=8)")
    res = sample_posterior(post, SamplerSettings(seed=0, max_steps=400, first_chunk=200))
    draws = res.draws(100, seed=0)
    load0 = os.getloadavg()[0]
    t_base, _ = median_time(lambda: analyse_residual(post, res, draws, n_permutations=0))
    t_full, full = median_time(lambda: analyse_residual(post, res, draws))
    load1 = os.getloadavg()[0]
    n = sum(r.n_scored for r in data)
    scan = full.drivers
    text = "\n".join([
        f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, {os.cpu_count()} "
        f"cores; load average {load0:.1f} at the start, {load1:.1f} at the end. Data: the "
        f"bundled virtual actuator, 5 records, {n} scored samples, two covariates; "
        f"{scan.n_units} units, {scan.n_permutations} sign patterns. Median of 3.", "",
        "| residual analysis | time [s] | vs baseline |", "|---|---|---|",
        f"| score tests only (baseline) | {t_base:.2f} | 1.00x |",
        f"| + driver scan + spectral lines | {t_full:.2f} | {t_full / t_base:.2f}x |", "",
        f"The scan found: {scan.summary()}."])
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("drivers", "Driver scan and spectral lines per residual", text)


if __name__ == "__main__":
    main()
