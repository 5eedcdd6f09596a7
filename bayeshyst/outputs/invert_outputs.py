"""What ``bayeshyst invert`` writes: ``command.csv`` and ``summary.json``.

``command.csv`` has one row per sample: ``t`` (s), ``u`` (the command, input unit),
``y_d`` (the reference), ``y_mean``, ``y_lo``, ``y_hi`` (the predicted output and its
90 % band, output unit). Both files are written atomically, ``summary.json`` last.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bayeshyst.files import atomic_path
from bayeshyst.inverse.command import CommandDesign
from bayeshyst.outputs.files import jsonable, write_json

__all__ = ["write_invert_outputs"]


def write_invert_outputs(design: CommandDesign, out: str | Path, *, fit_path: str,
                         reference_path: str, units: dict[str, str]) -> dict[str, Any]:
    """Write the command and its summary into ``out`` (created if needed).

    Parameters
    ----------
    design : CommandDesign
    out : path-like
    fit_path, reference_path : str
        Where the fit and the reference were read from (recorded in the summary).
    units : dict
        ``t``, ``u``, ``y`` units of the fit's data (recorded in the summary).

    Returns
    -------
    dict
        The summary written to ``summary.json``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with atomic_path(out / "command.csv") as tmp:
        design.to_dataframe().to_csv(tmp, index=False, float_format="%.10g")
    summary = {"command": "invert", **design.to_dict(), "fit": fit_path,
               "reference_file": reference_path, "units": dict(units),
               "columns": {"t": "s", "u": units.get("u", ""), "y_d": units.get("y", ""),
                           "y_mean": units.get("y", ""), "y_lo": units.get("y", ""),
                           "y_hi": units.get("y", "")},
               "files": {"command": "command.csv", "summary": "summary.json"}}
    summary = jsonable(summary)
    write_json(out / "summary.json", summary)
    return summary
