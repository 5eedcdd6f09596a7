"""Declared parameters: priors, transforms to the real line, and the parameter space.

Every quantity a sampler touches is a :class:`Param`: a name, a prior, a bijective
transform from its support to the real line (with the log-Jacobian of the inverse
map), a shape, a unit and a one-line description. A :class:`ParamSpace` is an ordered
collection of them; it maps the flat unconstrained vector ``z`` that emcee moves in to
the named physical values ``theta`` that models read, and evaluates the prior density
of ``z``::

    log p(z) = sum_i log p_i(x_i(z_i)) + log |dx_i/dz_i|

Fixed parameters stay in ``theta`` (so models always see every name) but leave ``z``.
Namespacing (``"static.w"``) lets composed models concatenate their spaces.

Priors and transforms are vectorised NumPy code: they are evaluated once per walker
per step and are never the bottleneck next to a simulation.
"""

from bayeshyst.params.priors import (
    HalfNormal,
    LogNormal,
    Normal,
    Prior,
    TruncatedNormal,
    Uniform,
)
from bayeshyst.params.space import Param, ParamSpace
from bayeshyst.params.transforms import (
    Identity,
    LogitTransform,
    LogTransform,
    ProbitTransform,
    Transform,
    UpperLogTransform,
)

__all__ = [
    "HalfNormal",
    "Identity",
    "LogNormal",
    "LogTransform",
    "LogitTransform",
    "Normal",
    "Param",
    "ParamSpace",
    "Prior",
    "ProbitTransform",
    "Transform",
    "TruncatedNormal",
    "Uniform",
    "UpperLogTransform",
]
