"""Fits checked on records they never saw: measured rigs of other kinds, with ``predict``.

The first check anyone in system identification makes -- fit on one record, simulate
the model on another, compare -- on the two measured sets that are not piezo stages:

* ``mr_damper`` -- the MR damper under sinusoidal displacement (mm in, N out,
  ``../shared/data/mr_damper_utfsm_sine``): at each coil current (``--currents``,
  default 0.5 A) the model (``--mr-model``, default Spencer's force form with the
  viscous term on the measured velocity) is fitted on ONE amplitude's record (25 mm at
  0.25 Hz) and predicted on every other amplitude's record at the same current (2 mm at
  5 Hz, 5 mm at 3 Hz, 10 mm at 1 Hz, 25 mm at 0.1 and 0.5 Hz), each from the relaxed
  state at its first input with its own warm-up not scored;
* ``boucwen_benchmark`` -- the Noel-Schoukens Bouc-Wen benchmark (force in N,
  displacement in m, 750 Hz, read from its published HDF5 files): the model
  (``--bw-model``) is fitted on the last period of the training multisine (the
  period before it simulated as warm-up; the training file only; ``--quick``: the last
  2 048 samples after 1 024) and predicted on the test
  multisine in periodic steady state (``periodic:3``) and on the sine sweep from rest;
  the free-run RMSE is given in metres beside the published results.

Every prediction is :meth:`bayeshyst.inference.saved.SavedFit.predict` on the fit
read back from its ``posterior.nc`` (what ``bayeshyst predict FIT DATA`` runs), and its
RMSE is checked against an independent simulation of the same draws, one draw at a
time, before it is reported.

Outputs in ``--out``: ``predictions.csv`` (one row per case, model and record: RMSE,
NRMSE, fit %, max error, band coverage and its calibrated range), ``predict.txt``,
per case the fit (``<case>/fit/``) and the prediction outputs
(``<case>/predict_<record>/``), and ``summary.json`` (written last).

Run (from the repository root)::

    python -m analyses.predict_unseen                  # both cases, converged fits
    python -m analyses.predict_unseen --quick          # a smoke run: 300 steps, NOT converged
    python -m analyses.predict_unseen --cases mr_damper --currents 0,0.5,1
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from analyses._common import (
    EXIT_OK,
    Progress,
    base_parser,
    budget,
    name_list,
    positive_int,
    run,
    slug,
    write_csv,
    write_text,
)
from bayeshyst import diagnostics
from bayeshyst.data import label_frequencies, load_bouc_wen_benchmark, load_mr_damper
from bayeshyst.data.dataset import Dataset
from bayeshyst.errors import DataError
from bayeshyst.inference.fit import fit_model
from bayeshyst.inference.saved import load_fit
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.outputs import write_fit_outputs
from bayeshyst.outputs.files import write_json
from bayeshyst.outputs.predict_outputs import write_predict_outputs

PROG = "predict_unseen"
CASES = ("mr_damper", "boucwen_benchmark")
#: Spencer's force form of Bouc-Wen with the damper's viscous term on its velocity column
MR_MODEL = "bouc_wen(sign=1, parametrisation='saturation')+aux(column='velocity_mm_s')"
#: the MR record every fit is made on: (amplitude mm, frequency Hz)
MR_TRAIN = (25.0, 0.25)
BW_MODEL = "pi_play+second_order"
#: published free-run RMSE on the test multisine [m] (Schoukens & Noel 2017 and the
#: papers of the results named; see ../shared/data/boucwen_benchmark/SOURCE.md)
PUBLISHED_RMSE_M = {"state-space neural network (best published)": 7.53e-6,
                    "PNLSS": (1.2e-5, 1.9e-5), "dynoNet": 4.5e-5, "linear model": 1.6e-4}
COLUMNS = ("case", "model", "record", "initial", "converged", "n", "rmse", "unit",
           "rmse_m", "nrmse_percent", "fit_percent", "max_error", "coverage_50",
           "expected_50_lo", "expected_50_hi", "coverage_90", "expected_90_lo",
           "expected_90_hi", "calibrated", "independent_rmse_error")
#: the benchmark's training samples scored (the last ones of the file) and the warm-up
#: simulated before them: quick mode fits a quarter period, full mode the last period
QUICK = {"sampler": SamplerSettings(max_steps=300, first_chunk=100), "draws": 40,
         "cases": CASES, "currents": (0.5,), "mr_model": MR_MODEL, "bw_model": BW_MODEL,
         "bw_train": (2048, 1024)}
FULL = {"sampler": SamplerSettings(), "draws": 400, "cases": CASES, "currents": (0.5,),
        "mr_model": MR_MODEL, "bw_model": BW_MODEL, "bw_train": (8192, 8192)}
#: metres per unit of a length the records may carry (the benchmark's m may be
#: converted to the working unit um on reading)
_METRES = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "nm": 1e-9}


def _currents(text: str) -> tuple[float, ...]:
    """An argparse type: coil currents [A], ``"0,0.5,1"``, each >= 0."""
    try:
        out = tuple(float(p) for p in text.split(",") if p.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected currents separated by commas, got "
                                         f"{text!r}") from None
    if not out or not all(math.isfinite(c) and c >= 0 for c in out):
        raise argparse.ArgumentTypeError(f"expected currents >= 0 [A], got {text!r}")
    return out


def _independent_rmse(fit: Any, result: Any, z: np.ndarray, record: Any) -> float:
    """|RMSE reported - RMSE of a one-draw-at-a-time simulation of the same draws|."""
    post = fit.posterior
    theta = post.space.unpack(z)
    rec = result[record.name]
    initial = result.initial
    u, t = record.u, record.t
    cov = {c: record.covariates[c] for c in post.model.covariates}
    if initial.kind == "periodic":
        k = initial.periods
        u, t = np.tile(u, k), np.concatenate([t + j * (record.duration + record.dt)
                                             for j in range(k)])
        cov = {c: np.tile(v, k) for c, v in cov.items()}
    sims = []
    for i in range(z.shape[0]):
        one = {n: np.asarray(theta[n])[i] for n in post.model_space.all_names}
        state0 = (post.model.initial_state(one, 0.0) if initial.kind == "rest" else None)
        y = post.model.simulate(u, t, one, state0=state0, covariates=cov or None)
        off = float(np.asarray(theta["obs.offset"])[i]) if post.offset else 0.0
        sims.append(y[-record.n:] + off)
    e = (record.y - np.mean(sims, axis=0))[rec.scored]
    return abs(float(np.sqrt(np.mean(e**2))) - result.per_record[
        [r.name for r in result.records].index(record.name)].rmse)


def _fit(case: str, data: Dataset, model: str, cfg: dict[str, Any], out: Path,
         say: Progress) -> Any:
    say(f"{case}: fitting {model} on {', '.join(r.name for r in data)}")
    fit = fit_model(data, model, "gaussian", sampler=cfg["sampler"])
    idata = diagnostics.to_inference_data(fit.posterior, fit.sampling, seed=cfg["sampler"].seed)
    write_fit_outputs(fit, out / case / "fit", idata=idata)
    say(f"  {'converged' if fit.converged else 'NOT converged'} in "
        f"{fit.sampling.runtime_s:.0f} s")
    return load_fit(out / case / "fit")


def _predict(case: str, saved: Any, data: Dataset, initial: str, cfg: dict[str, Any],
             args: argparse.Namespace, out: Path, say: Progress) -> list[dict[str, Any]]:
    rows = []
    result = saved.predict(data, initial=initial, n_draws=cfg["draws"], seed=args.seed)
    figures = None
    if not args.no_figures:
        from bayeshyst.outputs.assemble import prediction_figures

        figures = prediction_figures(result)
    write_predict_outputs(result, out / case / f"predict_{slug(data.name)}",
                          fit_path=str(saved.path), data_path=data.name, figures=figures)
    z = saved.draws(min(cfg["draws"], saved.n_draws), seed=args.seed)
    unit = result.units["y"]
    for rec, score in zip(data, result.per_record, strict=True):
        err = _independent_rmse(saved, result, z, rec)
        span = float(np.ptp(rec.y))
        if not err <= 1e-9 * span:
            raise DataError(f"{case}, {rec.name}: the reported RMSE differs from an "
                            f"independent simulation of the same draws by {err:.3g} "
                            f"{unit} (> 1e-9 of the output span)")
        d = score.to_dict()
        rows.append({"case": case, "model": result.model, "record": rec.name,
                     "initial": result.initial.kind, "converged": saved.converged,
                     "n": d["n_samples"], "rmse": d["rmse"], "unit": unit,
                     "rmse_m": d["rmse"] * _METRES[unit] if unit in _METRES else math.nan,
                     "nrmse_percent": d["nrmse_percent"], "fit_percent": d["fit_percent"],
                     "max_error": d["max_error"], "coverage_50": d["coverage_50"],
                     "expected_50_lo": d["expected_50"][0],
                     "expected_50_hi": d["expected_50"][1], "coverage_90": d["coverage_90"],
                     "expected_90_lo": d["expected_90"][0],
                     "expected_90_hi": d["expected_90"][1], "calibrated": d["calibrated"],
                     "independent_rmse_error": err})
        say(f"  {rec.name} ({result.initial.kind}): {score}")
    return rows


def _mr_damper(cfg: dict[str, Any], args: argparse.Namespace, out: Path,
               say: Progress) -> list[dict[str, Any]]:
    rows = []
    for current in cfg["currents"]:
        data = load_mr_damper(current_a=current)
        train = [r for r in data if (r.metadata["amplitude_mm"], r.metadata["frequency_hz"])
                 == MR_TRAIN]
        if len(train) != 1:
            raise DataError(f"mr_damper at {current:g} A: no single {MR_TRAIN[0]:g} mm / "
                            f"{MR_TRAIN[1]:g} Hz record to fit on")
        case = f"mr_damper_{current:g}A"
        saved = _fit(case, Dataset(train, name=f"{case}_train"), cfg["mr_model"], cfg, out,
                     say)
        others = Dataset([r for r in data if r.name != train[0].name], name=f"{case}_others")
        rows += _predict(case, saved, others, "relaxed", cfg, args, out, say)
    return rows


def _benchmark(cfg: dict[str, Any], args: argparse.Namespace, out: Path,
               say: Progress) -> list[dict[str, Any]]:
    (train,) = load_bouc_wen_benchmark("train")
    scored, warm = cfg["bw_train"]
    # the last samples, after a warm-up simulated from the relaxed state: the scored
    # part starts from the state the multisine left (the file's first period from rest)
    part = train.slice(train.n - scored - warm, train.n, warmup=warm,
                       name=f"train_last_{scored}")
    # classified as a file is: a multisine (its held-out units periods, not fake cycles)
    saved = _fit("boucwen_benchmark", label_frequencies(Dataset((part,), name="boucwen_train")),
                 cfg["bw_model"], cfg, out, say)
    # classified as the command line classifies a file: the sweep and the one-period
    # multisine are kept whole and scored in their band groups (with an error spectrum)
    rows = _predict("boucwen_benchmark", saved,
                    label_frequencies(load_bouc_wen_benchmark("test_multisine")),
                    "periodic:3", cfg, args, out, say)
    rows += _predict("boucwen_benchmark", saved,
                     label_frequencies(load_bouc_wen_benchmark("test_sweep")), "rest", cfg,
                     args, out, say)
    return rows


def _analyse(args: argparse.Namespace) -> int:
    cfg = budget(args, QUICK, FULL, {"cases": args.cases, "currents": args.currents,
                                     "mr_model": args.mr_model, "bw_model": args.bw_model,
                                     "draws": args.draws})
    unknown = [c for c in cfg["cases"] if c not in CASES]
    if unknown:
        raise DataError(f"--cases: unknown case(s) {unknown}; expected some of {CASES}")
    say = Progress(PROG, args.quiet)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    if "mr_damper" in cfg["cases"]:
        rows += _mr_damper(cfg, args, out, say)
    if "boucwen_benchmark" in cfg["cases"]:
        rows += _benchmark(cfg, args, out, say)
    write_csv(out / "predictions.csv", COLUMNS, rows)
    converged = all(r["converged"] for r in rows)
    lines = ["PREDICTION ON RECORDS THE FIT NEVER SAW"]
    if not converged:
        lines.append("WARNING: some fits did NOT converge; their numbers are provisional")
    for r in rows:
        metres = "" if math.isnan(r["rmse_m"]) else f" = {r['rmse_m']:.3g} m"
        lines.append(f"{r['case']:>20} {r['record']:>16} ({r['initial']}): RMSE "
                     f"{r['rmse']:.4g} {r['unit']}{metres} ({r['nrmse_percent']:.2f} %), fit "
                     f"{r['fit_percent']:.1f} %, 90 % band {100 * r['coverage_90']:.1f} % "
                     f"(calibrated {100 * r['expected_90_lo']:.0f}-"
                     f"{100 * r['expected_90_hi']:.0f} %)")
    if "boucwen_benchmark" in cfg["cases"]:
        lines.append("published test-multisine RMSE [m]: " + "; ".join(
            f"{k} {v if isinstance(v, float) else f'{v[0]}-{v[1]}'}"
            for k, v in PUBLISHED_RMSE_M.items()))
    write_text(out / "predict.txt", "\n".join(lines))
    write_json(out / "summary.json", {
        "analysis": PROG, "quick": bool(args.quick), "seed": args.seed,
        "settings": {k: (v.to_dict() if hasattr(v, "to_dict") else v)
                     for k, v in cfg.items()},
        "rows": rows, "published_rmse_m": PUBLISHED_RMSE_M, "converged": converged,
        "runtime_s": say.elapsed})
    print("\n".join(lines))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    parser = base_parser(PROG, __doc__)
    parser.add_argument("--cases", type=name_list, default=None,
                        help=f"some of {', '.join(CASES)} (default both)")
    parser.add_argument("--currents", type=_currents, default=None,
                        help="MR damper coil currents [A] (default 0.5)")
    parser.add_argument("--mr-model", default=None, help=f"default {MR_MODEL}")
    parser.add_argument("--bw-model", default=None, help=f"default {BW_MODEL}")
    parser.add_argument("--draws", type=positive_int, default=None,
                        help="posterior draws per prediction (default 400; quick 40)")
    parser.add_argument("--steps", type=positive_int, default=None,
                        help="max sampler steps per ensemble (default: converge)")
    args = parser.parse_args(argv)
    return run(PROG, _analyse, args)


if __name__ == "__main__":
    raise SystemExit(main())
