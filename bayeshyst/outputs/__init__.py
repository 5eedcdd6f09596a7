"""Writers of what users read: summary JSON, figures, netCDF posteriors, reports."""

from __future__ import annotations

from bayeshyst.outputs.files import atomic_path, jsonable, write_json
from bayeshyst.outputs.fit_outputs import fit_summary, write_fit_outputs

__all__ = ["atomic_path", "fit_summary", "jsonable", "write_fit_outputs", "write_json"]
