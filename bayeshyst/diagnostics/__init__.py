"""Conversion of sampling results to ``arviz.InferenceData``, netCDF files, LOO and WAIC.

This is the only package of bayeshyst that imports arviz: the conversion, files and
summaries in :mod:`~bayeshyst.diagnostics.inference_data`, PSIS-LOO and WAIC in
:mod:`~bayeshyst.diagnostics.elpd`. Everything it hands back to the rest of the package
(and to users who do not want arviz objects) is a plain frozen dataclass:
:class:`ElpdResult` for PSIS-LOO and WAIC, :class:`GroupElpd` for their sums over groups
of cycles (per excitation frequency, per record). Two estimators go further than
PSIS-LOO on a sampled posterior: :mod:`~bayeshyst.diagnostics.moment_match` (moved
draws, for cycles with a large Pareto k) and :mod:`~bayeshyst.diagnostics.laplace_loo`
(a posterior not sampled at all, scored from its MAP: the diagnosis' screen).

Why the InferenceData is thinned: see :mod:`~bayeshyst.diagnostics.inference_data`.
"""

from bayeshyst.diagnostics.elpd import (
    PARETO_K_BAD,
    ElpdResult,
    GroupElpd,
    elpd_by_group,
    loo,
    waic,
)
from bayeshyst.diagnostics.inference_data import (
    GIVEN_REST,
    load_netcdf,
    posterior_summary,
    sampling_report,
    save_netcdf,
    to_inference_data,
)

__all__ = [
    "GIVEN_REST",
    "PARETO_K_BAD",
    "ElpdResult",
    "GroupElpd",
    "elpd_by_group",
    "load_netcdf",
    "loo",
    "posterior_summary",
    "sampling_report",
    "save_netcdf",
    "to_inference_data",
    "waic",
]
