"""What ``bayeshyst export`` writes: the inverse as JSON, C99 source or a table.

Every file is written atomically and ``summary.json`` last:

* ``inverse.json`` -- always: :meth:`~bayeshyst.inverse.export.InverseExport.to_dict`;
* ``--format c``: ``<prefix>_inverse.h`` and ``<prefix>_inverse.c``;
* ``--format table``: ``inverse_table.csv`` (``y_up, u_up, y_down, u_down``);
* ``--reference``: ``replay.csv`` (``t, y_d, u``: the exported inverse's command).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from bayeshyst.files import atomic_path
from bayeshyst.inverse.export import InverseExport
from bayeshyst.outputs.files import jsonable, write_json

__all__ = ["write_export_outputs"]


def _text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def write_export_outputs(export: InverseExport, out: str | Path, *, fmt: str, prefix: str,
                         fit_path: str, replay: dict[str, Any] | None = None
                         ) -> dict[str, Any]:
    """Write the export into ``out`` (created if needed) and return the summary.

    Parameters
    ----------
    export : InverseExport
    out : path-like
    fmt : {"json", "c", "table"}
    prefix : str
        C identifier prefix and file-name prefix of the C files.
    fit_path : str
        Where the fit was read from.
    replay : dict, optional
        ``t``, ``y_d``, ``u`` arrays and ``error_percent`` / ``reference`` of a replay on
        a reference.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = ["inverse.json"]
    _text(out / "inverse.json", json.dumps(jsonable(export.to_dict()), indent=1) + "\n")
    if fmt == "c":
        header, source = export.c_code(prefix)
        _text(out / f"{prefix}_inverse.h", header)
        _text(out / f"{prefix}_inverse.c", source)
        files += [f"{prefix}_inverse.h", f"{prefix}_inverse.c"]
    elif fmt == "table":
        p = export.parameters
        rows = np.column_stack([p["y_up"], p["u_up"], p["y_down"], p["u_down"]])
        with atomic_path(out / "inverse_table.csv") as tmp:
            np.savetxt(tmp, rows, delimiter=",", fmt="%.17g",
                       header="y_up,u_up,y_down,u_down", comments="")
        files.append("inverse_table.csv")
    summary: dict[str, Any] = {"command": "export", "format": fmt, "fit": fit_path,
                               **{k: v for k, v in export.to_dict().items()
                                  if k != "parameters"}}
    if replay is not None:
        with atomic_path(out / "replay.csv") as tmp:
            np.savetxt(tmp, np.column_stack([replay["t"], replay["y_d"], replay["u"]]),
                       delimiter=",", fmt="%.17g", header="t,y_d,u", comments="")
        files.append("replay.csv")
        summary["replay"] = {"reference": replay["reference"],
                             "error_percent_of_command_span": replay["error_percent"]}
    files.append("summary.json")
    summary["files"] = files
    summary = jsonable(summary)
    write_json(out / "summary.json", summary)
    return summary
