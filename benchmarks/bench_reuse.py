"""Reusing a fit instead of refitting: load_fit, invert and export against the fit itself.

The baseline, measured in the same run, is what a user did before ``load_fit`` existed:
``fit_model`` again (default sampler settings, seed 0) on the bundled virtual actuator's
records. Against it: writing the posterior (``to_inference_data`` + netCDF), reading it
back with ``load_fit`` (rebuild + check of the recorded log densities), designing a
posterior-mean command for a 2-cycle reference (``design_command``), and exporting the
inverse (``export_inverse`` + C source). Each is timed as the median of 3 runs (the fit
once: it is the slow one).

Usage::

    python benchmarks/bench_reuse.py [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._results import median_time  # noqa: E402  (after the path)

MODELS = ("pi_play(n_operators=8)", "bouc_wen")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = parser.parse_args()
    from bayeshyst import diagnostics
    from bayeshyst.data import load
    from bayeshyst.demo import bundled_data
    from bayeshyst.inference.fit import fit_model
    from bayeshyst.inference.saved import load_fit
    from bayeshyst.inference.settings import SamplerSettings
    from bayeshyst.inverse.command import design_command
    from bayeshyst.inverse.export import export_inverse
    from bayeshyst.inverse.references import reference_signal

    data = load(bundled_data()).select((1.0, 10.0))
    load0 = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for spec in MODELS:
            t0 = time.perf_counter()
            fit = fit_model(data, spec, sampler=SamplerSettings(seed=0))
            t_fit = time.perf_counter() - t0
            path = Path(tmp) / f"{len(rows)}.nc"

            def save(fit=fit, path=path):
                idata = diagnostics.to_inference_data(fit.posterior, fit.sampling, seed=0)
                diagnostics.save_netcdf(idata, path)

            t_save, _ = median_time(save)
            t_load, saved = median_time(lambda path=path: load_fit(path))
            y = np.concatenate([r.y for r in data])
            ref = reference_signal("sine", 10.0, data[0].fs, float(np.quantile(y, 0.1)),
                                   float(np.quantile(y, 0.9)))
            t_cmd, _ = median_time(lambda saved=saved, ref=ref: design_command(saved, ref))
            t_exp, _ = median_time(lambda saved=saved: export_inverse(saved).c_code())
            rows.append((spec, t_fit, t_save, t_load, t_cmd, t_exp, saved.max_log_prob_error,
                         bool(fit.converged)))
    load1 = os.getloadavg()[0]
    lines = [f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, "
             f"{os.cpu_count()} cores; load average {load0:.1f} at the start, {load1:.1f} at "
             "the end. Data: the bundled virtual actuator at 1 and 10 Hz (2 records). Times "
             "in seconds (median of 3; the fit once).", "",
             "| model | fit (baseline) | save | load_fit | command | export | load / fit | "
             "log p check [nats] | converged |",
             "|---|---|---|---|---|---|---|---|---|"]
    for spec, t_fit, t_save, t_load, t_cmd, t_exp, err, conv in rows:
        lines.append(f"| {spec} | {t_fit:.2f} | {t_save:.2f} | {t_load:.3f} | {t_cmd:.2f} | "
                     f"{t_exp:.3f} | {t_load / t_fit:.3f}x | {err:.1e} | {conv} |")
    lines.append("")
    for spec, t_fit, _, t_load, t_cmd, _, _, _ in rows:
        lines.append(f"- {spec}: reloading and designing a command takes "
                     f"{(t_load + t_cmd) / t_fit:.2f}x the refit it replaces "
                     f"({t_load + t_cmd:.2f} s vs {t_fit:.2f} s).")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from benchmarks._results import write_section

        write_section("reuse", "Reusing a fit: load_fit, invert, export", text)


if __name__ == "__main__":
    main()
