"""Transfer check on measured data: fit on one file, predict another driven differently.

Answers the question a user designing feedforward from a posterior has to answer first:
*does the predictive band hold on an input the model was not fitted on?* The measured
piezo micromanipulator (``../shared/data/piezo_micromanipulator_dbo``) comes with two
files: ``Model_Vi_Do.dat``, ~40 cycles of one 1 Hz drive, for identification, and
``Test_Vi_Do_Di.dat``, a validation run of growing- and decaying-amplitude oscillations
(nested minor loops), whose last two segments were driven through the authors' inverse
model to follow a desired output (column 9). Every model (``--models``) is fitted on the
identification file, with and without the model discrepancy (``--discrepancy``), and
:func:`bayeshyst.inverse.validation.check_transfer` predicts the test file from its
applied voltage -- with the identification file's sensor zero, re-zeroed on the test
file's lead-in, and re-zeroed with the residual learned on the uncompensated segments
for the inverse-driven ones (:data:`OFFSETS`): per segment the coverage of the 50 % and
90 % predictive bands (draws plus a residual resampled onto the test input) against the
range a calibrated predictive gives, the prediction's NRMSE and mean offset, and in the
inverse-driven segments the measured tracking error against the band predicted for it.

Two facts of the files are applied as the authors' scripts do and recorded in
``summary.json``: the test file's sensor reading is taken one sample later (their
scripts align it so; the identification file has no lag), and the desired output, given
with its mean removed, is placed at the test file's mean reading.

Outputs in ``--out``: ``transfer.csv`` (one row per model x discrepancy x segment),
``transfer.txt`` and ``summary.json`` (written last).

Run (from the repository root)::

    python -m analyses.transfer_check                 # bouc_wen, none and hsgp, converged
    python -m analyses.transfer_check --quick         # seconds: 300 steps, NOT converged
    python -m analyses.transfer_check --models "bouc_wen,pi_play(n_operators=8)"
"""

from __future__ import annotations

import argparse
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
    write_csv,
    write_text,
)
from bayeshyst.data import measured
from bayeshyst.data.dataset import Dataset
from bayeshyst.data.record import Record
from bayeshyst.inference.fit import fit_model
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.inverse.validation import check_transfer
from bayeshyst.outputs.files import write_json

PROG = "transfer_check"
#: How the test file is predicted: with the identification file's sensor zero
#: ("fitted"); re-zeroed on its lead-in segment 0 ("rezeroed"; segment 0 then left out);
#: re-zeroed, and with the residual learned on the uncompensated segments 1-2 for the
#: inverse-driven segments 3-4 ("learned": the transfer error measured on paths like
#: theirs, nested minor loops, instead of the identification loops').
OFFSETS = ("fitted", "rezeroed", "learned")
COLUMNS = ("model", "discrepancy", "offset", "converged", "window", "n", "n_effective",
           "coverage_50", "expected_50_lo", "expected_50_hi", "coverage_90",
           "expected_90_lo", "expected_90_hi", "calibrated", "nrmse_percent", "bias",
           "tracking_percent", "tracking_band_lo", "tracking_band_hi", "tracking_inside")
QUICK = {"sampler": SamplerSettings(max_steps=300, first_chunk=100), "models": ("bouc_wen",),
         "discrepancies": ("none", "hsgp"), "draws": 100}
FULL = {"sampler": SamplerSettings(), "models": ("bouc_wen",),
        "discrepancies": ("none", "hsgp"), "draws": 400}


def test_record(root: Any = None) -> tuple[Record, np.ndarray]:
    """The test file as one record (sensor one sample later) and its placed reference."""
    rec = measured.load_piezo_micromanipulator(root, which="test")[0]
    lag = int(rec.metadata.get("phase_lag_samples", 0))
    y_d = np.asarray(measured.load_micromanipulator_reference(root), float)
    if lag:
        # the reading at k + lag answers the voltage at k; the last lag samples go
        keep = rec.n - lag
        rec = Record(t=rec.t[:keep], u=rec.u[:keep], y=rec.y[lag:], segment=rec.segment[:keep],
                     warmup=rec.warmup, metadata={**rec.metadata, "aligned_by_samples": lag},
                     units=dict(rec.units), name=rec.name)
        y_d = y_d[:keep]
    return rec, y_d + float(np.mean(rec.y))


def _rows(model: str, disc: str, offset: str, converged: bool, chk: Any) -> list[dict]:
    out = []
    for w in chk.windows:
        band = w.tracking_band_percent or (None, None)
        # "off", not "none": a table cell "none" reads as a missing value
        out.append({"model": model, "discrepancy": "off" if disc == "none" else disc,
                    "offset": offset, "converged": converged, "window": w.label, "n": w.n,
                    "n_effective": w.n_effective, "coverage_50": w.coverage[0.5],
                    "expected_50_lo": w.expected[0.5][0], "expected_50_hi": w.expected[0.5][1],
                    "coverage_90": w.coverage[0.9], "expected_90_lo": w.expected[0.9][0],
                    "expected_90_hi": w.expected[0.9][1], "calibrated": w.calibrated,
                    "nrmse_percent": w.nrmse_percent, "bias": w.bias,
                    "tracking_percent": w.tracking_percent, "tracking_band_lo": band[0],
                    "tracking_band_hi": band[1], "tracking_inside": w.tracking_inside})
    return out


def _analyse(args: argparse.Namespace) -> int:
    cfg = budget(args, QUICK, FULL, {"models": args.models,
                                     "discrepancies": args.discrepancy})
    say = Progress(PROG, args.quiet)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ident = measured.load_piezo_micromanipulator(which="model")
    rec, y_d = test_record()
    test = Dataset((rec,), name=rec.name)
    rows: list[dict[str, Any]] = []
    runs = []
    for model in cfg["models"]:
        for disc in cfg["discrepancies"]:
            say(f"fitting {model} (discrepancy {disc}) on the identification file")
            fit = fit_model(ident, model, "gaussian", sampler=cfg["sampler"],
                            discrepancy=disc)
            say(f"  {'converged' if fit.converged else 'NOT converged'}; predicting the "
                "test file")
            z = fit.sampling.draws(cfg["draws"], seed=args.seed)
            for offset in OFFSETS:
                zero = None if offset == "fitted" else {rec.name: rec.segment == 0}
                learn = ({rec.name: (rec.segment == 1) | (rec.segment == 2)}
                         if offset == "learned" else None)
                chk = check_transfer(fit.posterior, z, test, reference={rec.name: y_d},
                                     rezero=zero, residual_from=learn, seed=args.seed)
                runs.append({"model": model, "discrepancy": disc, "offset": offset,
                             "converged": fit.converged, "check": chk.to_dict()})
                rows += _rows(model, disc, offset, fit.converged, chk)
                say(str(chk))
    write_csv(out / "transfer.csv", COLUMNS, rows)
    compensated = dict(zip(range(1, 5), rec.metadata["window_compensation"], strict=True))
    lines = ["TRANSFER CHECK: fitted on the identification file, predicting the test file",
             f"segments: {compensated} (0: lead-in)", ""]
    for r in runs:
        state = "converged" if r["converged"] else "NOT converged"
        lines.append(f"== {r['model']}, discrepancy {r['discrepancy']}, offset {r['offset']} "
                     f"({state})")
        lines += [f"  {w['label']}: 90 % band {100 * w['coverage']['0.9']:.1f} % (expected "
                  f"{100 * w['expected']['0.9'][0]:.0f}-{100 * w['expected']['0.9'][1]:.0f}), "
                  f"50 % band {100 * w['coverage']['0.5']:.1f} %, NRMSE "
                  f"{w['nrmse_percent']:.2f} %, bias {w['bias']:+.3f}"
                  + ("" if w["tracking_percent"] is None else
                     f", tracking {w['tracking_percent']:.2f} % vs "
                     f"[{w['tracking_band_percent'][0]:.2f}, "
                     f"{w['tracking_band_percent'][1]:.2f}] %")
                  for w in r["check"]["windows"]]
        lines += [f"  warning: {w}" for w in r["check"]["warnings"]]
    write_text(out / "transfer.txt", "\n".join(lines))
    write_json(out / "summary.json", {
        "analysis": PROG, "quick": bool(args.quick), "seed": args.seed,
        "identification": ident[0].name, "test": rec.name,
        "alignment": {"test_sensor_later_by_samples": rec.metadata.get("aligned_by_samples",
                                                                       0),
                      "reference_placed_at": "the test file's mean reading"},
        "segments": compensated, "runs": runs,
        "converged": all(r["converged"] for r in runs)})
    print("\n".join(lines))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    parser = base_parser(PROG, __doc__)
    parser.add_argument("--models", type=name_list, default=None,
                        help="model specs, comma-separated (default bouc_wen)")
    parser.add_argument("--discrepancy", type=name_list, default=None,
                        help="none and/or hsgp (default both)")
    parser.add_argument("--steps", type=positive_int, default=None,
                        help="max sampler steps per ensemble (default: converge, <= 20 000)")
    args = parser.parse_args(argv)
    return run(PROG, _analyse, args)


if __name__ == "__main__":
    raise SystemExit(main())
