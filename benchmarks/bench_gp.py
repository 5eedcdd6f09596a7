"""GP hysteresis model on 10^5-sample records: error and time against the subset size.

Data (virtual actuator with hysteresis, 1.5 kHz dynamics and 50 us delay, creep and
drift off, white noise 0.04 um; 10 kHz sampling):

* training record, ~1.0e5 samples: decaying sines (nested minor loops, 75 V -> 5-10 V)
  at 2, 5, 10, 25 and 50 Hz, joined by raised-cosine ramps;
* held-out record, ~1.0e5 samples: the same kind at 3, 7, 15, 35 and 45 Hz with other
  decays -- frequencies and loop sizes the training never saw.

For each variant (``memory``, ``rate``), subset scheme (``stratified``, ``farthest``)
and ``n_train`` in 125 ... 2000, in one run: the fit time (subset choice + marginal
likelihood maximisation with the default 2 restarts), the free-run prediction time on
all held-out samples (mean only, and mean and std), the NRMSE of the free run against
the noise-free truth (scored samples, % of peak-to-peak), and the fit time relative to
an exact GP on all training samples, extrapolated from the measured cost of one
likelihood evaluation at the largest ``n_train`` by O(N^3) (its kernel matrix alone
would take N^2 * 8 bytes).

Usage::

    python benchmarks/bench_gp.py [--quick] [--write]
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
FS = 10_000.0
TRAIN = ((2, 4, 7.5), (5, 10, 10.0), (10, 20, 5.0), (25, 50, 10.0), (50, 100, 7.5))
HELD = ((3, 6, 15.0), (7, 14, 5.0), (15, 30, 10.0), (35, 70, 5.0), (45, 90, 20.0))


def make_record(spec, seed: int, name: str, scale: float = 1.0):
    """Decaying sines (frequency [Hz], cycles, final amplitude [V]) joined at 10 kHz."""
    from bayeshyst.data import excitation as ex
    from bayeshyst.data.virtual import AR1Noise, VirtualActuator

    act = VirtualActuator().without("creep", "drift").with_effects(noise=AR1Noise(0.04, 0.0))
    segs = [ex.decaying_sine(f, FS, cycles=max(1, round(c * scale)), final_amplitude_v=a)
            for f, c, a in spec]
    t, u = ex.concatenate(segs, FS, ramp_s=0.05)
    rec = act.record(t, u, rng=seed, name=name, warmup=int(0.25 * FS))
    return rec, act.without("noise").simulate(t, u)


def nrmse(pred: np.ndarray, truth: np.ndarray, warmup: int) -> float:
    err = (pred - truth)[warmup:]
    return 100 * float(np.sqrt(np.mean(err**2)) / np.ptp(truth))


def _duration(seconds: float) -> str:
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.1f} s"


def one_eval_seconds(est) -> float:
    """Time of one marginal-likelihood evaluation with gradient at the fitted optimum."""
    from bayeshyst.gp.kernel import blas_limit, log_marginal_likelihood

    z, y = est.gp_.X_train_, est.gp_.y_train_
    best = float("inf")
    with blas_limit(y.size):
        for _ in range(3):
            t0 = time.perf_counter()
            log_marginal_likelihood(est.kernel_.theta, est.kernel, z, y)
            best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1/10 of the data, n_train <= 500")
    ap.add_argument("--write", action="store_true", help="update benchmarks/RESULTS.md")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from bayeshyst.gp import GPHysteresis
    from benchmarks._results import write_section

    scale = 0.1 if args.quick else 1.0
    sizes = [125, 250, 500] if args.quick else [125, 250, 500, 1000, 2000]
    load0 = os.getloadavg()
    train, _ = make_record(TRAIN, 1, "train", scale)
    held, truth = make_record(HELD, 2, "held-out", scale)
    X = np.column_stack([held.t, held.u])
    print(f"training record {train.n} samples, held-out {held.n}; load average {load0}",
          flush=True)
    rows = []
    for features in ("memory", "rate"):
        for subset in ("stratified", "farthest"):
            for m in sizes:
                est = GPHysteresis(features=features, n_train=m, subset=subset, random_state=0)
                t0 = time.perf_counter()
                est.fit_records(train)
                fit_s = time.perf_counter() - t0
                t0 = time.perf_counter()
                mean = est.predict(X)
                pred_s = time.perf_counter() - t0
                t0 = time.perf_counter()
                est.predict(X, return_std=True)
                std_s = time.perf_counter() - t0
                row = {"features": features, "subset": subset, "m": m, "fit_s": fit_s,
                       "predict_s": pred_s, "predict_std_s": std_s,
                       "nrmse": nrmse(mean, truth, held.warmup),
                       "eval_s": one_eval_seconds(est), "converged": est.converged_,
                       "noise": est.noise_std_}
                rows.append(row)
                print(f"{features:7s} {subset:10s} m={m:5d}  fit {fit_s:7.1f} s  predict "
                      f"{pred_s:6.2f} s (+std {std_s:6.2f} s)  NRMSE {row['nrmse']:.3f} %  "
                      f"noise {est.noise_std_:.4f} um  converged {est.converged_}", flush=True)
    # exact GP on all N training samples: one likelihood evaluation extrapolated by m^3
    # from the largest subset (per variant), times as many evaluations as that fit took
    # (estimated as its fit time / the time of one evaluation)
    n_all = train.n
    head = ["variant", "subset", "n_train", "fit [s]", "predict mean [s]",
            "predict mean+std [s]", "held-out NRMSE [%]", "fit / exact-GP fit"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    refs = {}
    for features in ("memory", "rate"):
        big = max((r for r in rows if r["features"] == features), key=lambda r: r["m"])
        evals = big["fit_s"] / big["eval_s"]
        refs[features] = big["eval_s"] * (n_all / big["m"]) ** 3 * evals
    for r in rows:
        flag = "" if r["converged"] else " (optimiser not converged)"
        lines.append(f"| {r['features']} | {r['subset']} | {r['m']} | {r['fit_s']:.1f} | "
                     f"{r['predict_s']:.2f} | {r['predict_std_s']:.2f} | {r['nrmse']:.3f}{flag} | "
                     f"{r['fit_s'] / refs[r['features']]:.1e} |")
    text = "\n".join(lines)
    parts = []
    for f in refs:
        one = max(r["eval_s"] for r in rows if r["features"] == f) * (n_all / max(sizes)) ** 3
        parts.append(f"{f}: exact GP fit on all {n_all} samples ~ {_duration(refs[f])} "
                     f"(one likelihood evaluation ~ {_duration(one)})")
    note = "; ".join(parts)
    print()
    print(text)
    print(note)
    if args.write:
        import sklearn

        meta = (f"Measured {time.strftime('%Y-%m-%d')} on {platform.machine()}, "
                f"{os.cpu_count()} cores, Python {platform.python_version()}, numpy "
                f"{np.__version__}, scikit-learn {sklearn.__version__}; load average at the "
                f"start {load0[0]:.1f}, at the end {os.getloadavg()[0]:.1f} (another job was "
                f"running when the load exceeds ~0.5: times are then upper bounds). Training "
                f"record {train.n} samples (decaying sines at 2-50 Hz), held-out record "
                f"{held.n} samples (3-45 Hz); default settings (RBF, 2 optimiser restarts), "
                f"random_state=0; BLAS threads: OPENBLAS_NUM_THREADS="
                f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')} (training sets of <= 1000 "
                f"points always single-threaded). Kernel matrix of an exact GP: "
                f"{n_all**2 * 8 / 1e9:.0f} GB. {note}.")
        write_section("gp", "GP hysteresis model: subset size, error and time",
                      f"{meta}\n\n{text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
