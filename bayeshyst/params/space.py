"""Declared parameters and the parameter space that maps ``z`` to ``theta``.

A :class:`Param` is a name, a prior, a transform, a shape, a unit and a description; a
:class:`ParamSpace` orders them, packs and unpacks the flat unconstrained ``z`` and
evaluates its log prior density (priors in :mod:`bayeshyst.params.priors`, transforms
in :mod:`bayeshyst.params.transforms`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from bayeshyst.errors import ParameterError
from bayeshyst.params.priors import Prior
from bayeshyst.params.transforms import Transform

__all__ = ["Param", "ParamSpace"]


@dataclass(frozen=True)
class Param:
    """One declared parameter (scalar or array-valued).

    Parameters
    ----------
    name : str
        Name as models read it from ``theta`` (namespaced as ``"block.name"`` when
        composed).
    prior : Prior
        Prior applied elementwise.
    shape : tuple of int
        ``()`` for a scalar, ``(n,)`` for a vector of ``n`` elements.
    unit : str
        Physical unit of the value, e.g. ``"um/V"``.
    description : str
        One line saying what the parameter means.
    transform : Transform or None
        Map from the support to the real line; ``None`` takes the prior's default.
    """

    name: str
    prior: Prior
    shape: tuple[int, ...] = ()
    unit: str = ""
    description: str = ""
    transform: Transform | None = None

    def __post_init__(self) -> None:
        if not self.name or any(c.isspace() for c in self.name):
            raise ParameterError(f"parameter name must be non-empty without spaces: {self.name!r}")
        shape = tuple(int(s) for s in self.shape)
        if any(s < 1 for s in shape):
            raise ParameterError(f"parameter {self.name!r}: shape entries must be >= 1: {shape}")
        object.__setattr__(self, "shape", shape)
        if self.transform is None:
            object.__setattr__(self, "transform", self.prior.default_transform())

    @property
    def size(self) -> int:
        """Number of scalar elements."""
        return int(np.prod(self.shape, dtype=int)) if self.shape else 1

    def labels(self) -> list[str]:
        """Flat labels of the elements: ``name`` or ``name[0]``, ``name[1]``, ..."""
        if not self.shape:
            return [self.name]
        return [f"{self.name}[{','.join(map(str, idx))}]" for idx in np.ndindex(*self.shape)]

    def check_value(self, value: Any) -> np.ndarray:
        """Validate a physical value (shape and support); return it as a float array."""
        arr = np.asarray(value, dtype=float)
        if arr.shape != self.shape:
            raise ParameterError(
                f"parameter {self.name!r}: expected shape {self.shape}, got {arr.shape}"
            )
        lo, hi = self.prior.support
        bad = ~np.isfinite(arr) | (arr < lo) | (arr > hi)
        if np.any(bad):
            raise ParameterError(
                f"parameter {self.name!r}: value {arr[bad].ravel()[0]!r} outside the prior "
                f"support [{lo}, {hi}]"
            )
        return arr


# -------------------------------------------------------------------------- ParamSpace


@dataclass(frozen=True, eq=False)
class ParamSpace:
    """An ordered set of free parameters plus fixed values.

    Parameters
    ----------
    params : tuple of Param
        The free parameters in the order of the flat vector ``z``.
    fixed : mapping of str to array
        Parameters held at a value: they appear in ``theta`` but not in ``z``.
        Their declarations are kept in ``fixed_params`` so that ``free`` can release
        them again.

    Notes
    -----
    ``unpack`` accepts a single ``z`` of shape ``(ndim,)`` giving scalars / arrays of
    the declared shape, or a batch of shape ``(W, ndim)`` giving arrays with a leading
    ``W`` axis (fixed values are broadcast along it).
    """

    params: tuple[Param, ...] = ()
    fixed: Mapping[str, np.ndarray] = field(default_factory=lambda: MappingProxyType({}))
    fixed_params: tuple[Param, ...] = ()

    def __post_init__(self) -> None:
        params = tuple(self.params)
        object.__setattr__(self, "params", params)
        names = [p.name for p in params] + [p.name for p in self.fixed_params]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ParameterError(f"duplicate parameter names: {dupes}")
        frozen: dict[str, np.ndarray] = {}
        for p in self.fixed_params:
            if p.name not in self.fixed:
                raise ParameterError(f"fixed parameter {p.name!r} has no value")
            arr = p.check_value(self.fixed[p.name]).copy()
            arr.flags.writeable = False
            frozen[p.name] = arr
        extra = set(self.fixed) - set(frozen)
        if extra:
            raise ParameterError(f"fixed values given for undeclared parameters: {sorted(extra)}")
        object.__setattr__(self, "fixed", MappingProxyType(frozen))
        offsets, start = {}, 0
        for p in params:
            offsets[p.name] = (start, start + p.size)
            start += p.size
        object.__setattr__(self, "_offsets", MappingProxyType(offsets))
        object.__setattr__(self, "_ndim", start)

    def __reduce__(self) -> tuple[Any, ...]:
        # MappingProxyType does not pickle; rebuild through __init__ (which re-validates)
        return (ParamSpace, (self.params, dict(self.fixed), self.fixed_params))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ParamSpace):
            return NotImplemented
        return (
            self.params == other.params
            and self.fixed_params == other.fixed_params
            and all(np.array_equal(self.fixed[k], other.fixed[k]) for k in self.fixed)
        )

    __hash__ = None  # type: ignore[assignment]

    # ----------------------------------------------------------------- introspection
    @property
    def names(self) -> tuple[str, ...]:
        """Names of the free parameters, in ``z`` order."""
        return tuple(p.name for p in self.params)

    @property
    def all_names(self) -> tuple[str, ...]:
        """Names of free then fixed parameters (every key of ``theta``)."""
        return self.names + tuple(p.name for p in self.fixed_params)

    @property
    def ndim(self) -> int:
        """Length of the flat unconstrained vector ``z``."""
        return self._ndim  # type: ignore[attr-defined]

    @property
    def labels(self) -> list[str]:
        """One label per element of ``z`` (``w[0]``, ``w[1]``, ...)."""
        return [lab for p in self.params for lab in p.labels()]

    @property
    def declared_transforms(self) -> str:
        """The free parameters whose coordinate is not their prior's default, as text.

        A prior implies its default transform, so the table (``str``) names what is
        sampled up to these; a fit's identity and a checkpoint's fingerprint add them
        (a chain sampled in another coordinate is not the same run). Empty when every
        coordinate is the default.
        """
        return "; ".join(f"{p.name}: {p.transform!r}" for p in self.params
                         if p.transform != p.prior.default_transform())

    def __len__(self) -> int:
        return len(self.params)

    def __iter__(self) -> Iterator[Param]:
        return iter(self.params)

    def __contains__(self, name: object) -> bool:
        return name in self.all_names

    def __getitem__(self, name: str) -> Param:
        for p in self.params + self.fixed_params:
            if p.name == name:
                return p
        raise KeyError(f"no parameter named {name!r}; have {list(self.all_names)}")

    def slice_of(self, name: str) -> slice:
        """The slice of ``z`` that holds free parameter ``name``."""
        if name not in self._offsets:  # type: ignore[attr-defined]
            raise KeyError(f"{name!r} is not a free parameter; free: {list(self.names)}")
        a, b = self._offsets[name]  # type: ignore[attr-defined]
        return slice(a, b)

    @property
    def owners(self) -> tuple[str, ...]:
        """The free parameter that owns each coordinate of ``z`` (length ``ndim``)."""
        return tuple(name for name in self.names for _ in range(self[name].size))

    def indices(self, names: Iterable[str]) -> np.ndarray:
        """The ``z`` indices (int array, in the given order) of free parameters ``names``."""
        parts = [np.arange(self.ndim)[self.slice_of(n)] for n in names]
        return np.concatenate(parts) if parts else np.zeros(0, dtype=int)

    # ----------------------------------------------------------------- z <-> theta
    def _split(self, z: np.ndarray) -> tuple[np.ndarray, bool]:
        z = np.asarray(z, dtype=float)
        batched = z.ndim == 2
        if z.ndim not in (1, 2) or z.shape[-1] != self.ndim:
            raise ParameterError(
                f"z must have shape ({self.ndim},) or (W, {self.ndim}), got {z.shape}"
            )
        return (z if batched else z[None, :]), batched

    def unpack(self, z: np.ndarray, *, names: Iterable[str] | None = None) -> dict[str, Any]:
        """Named physical values from unconstrained ``z``.

        Parameters
        ----------
        z : ndarray, shape (ndim,) or (W, ndim)
        names : iterable of str, optional
            Only these parameters (free or fixed); default every one. A few coordinates
            of a long chain are transformed without the memory of all of them.

        Returns
        -------
        dict
            ``name -> value``: a float (scalar parameter) or an array of the declared
            shape; with a batch, arrays of shape ``(W, *shape)``.

        Raises
        ------
        KeyError
            A name in ``names`` that is no parameter of this space.
        """
        zz, batched = self._split(z)
        w = zz.shape[0]
        free, fixed = self.params, self.fixed_params
        if names is not None:
            chosen = [self[n] for n in names]
            free = tuple(p for p in chosen if p.name in self._offsets)  # type: ignore[attr-defined]
            fixed = tuple(p for p in chosen if p.name in self.fixed)
        theta: dict[str, Any] = {}
        for p in free:
            a, b = self._offsets[p.name]  # type: ignore[attr-defined]
            x = p.transform.inverse(zz[:, a:b]).reshape((w, *p.shape))
            theta[p.name] = x if batched else (float(x[0]) if not p.shape else x[0])
        for p in fixed:
            v = self.fixed[p.name]
            if batched:
                theta[p.name] = np.broadcast_to(v, (w, *p.shape))
            else:
                theta[p.name] = float(v) if not p.shape else v
        return theta

    def pack(self, theta: Mapping[str, Any]) -> np.ndarray:
        """Unconstrained ``z`` (shape ``(ndim,)``) from named physical values.

        Fixed parameters may be omitted; if given they must equal the fixed value.
        """
        missing = [n for n in self.names if n not in theta]
        if missing:
            raise ParameterError(f"theta is missing parameters {missing}")
        unknown = [n for n in theta if n not in self.all_names]
        if unknown:
            raise ParameterError(f"theta has unknown parameters {unknown}; known "
                                 f"{list(self.all_names)}")
        z = np.empty(self.ndim)
        for p in self.params:
            x = p.check_value(theta[p.name])
            z[self.slice_of(p.name)] = p.transform.forward(x).ravel()
        for p in self.fixed_params:
            if p.name in theta and not np.array_equal(np.asarray(theta[p.name], float),
                                                     self.fixed[p.name]):
                raise ParameterError(
                    f"parameter {p.name!r} is fixed at {self.fixed[p.name]!r}, theta gives "
                    f"{theta[p.name]!r}"
                )
        return z

    def log_prior(self, z: np.ndarray) -> float | np.ndarray:
        """Log prior density of ``z``, Jacobian included.

        Returns a float for ``z`` of shape ``(ndim,)`` and an array ``(W,)`` for a
        batch. The value is finite or ``-inf``, never NaN.
        """
        zz, batched = self._split(z)
        total = np.zeros(zz.shape[0])
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            for p in self.params:
                a, b = self._offsets[p.name]  # type: ignore[attr-defined]
                zp = zz[:, a:b]
                x = p.transform.inverse(zp)
                total += np.sum(p.prior.logpdf(x) + p.transform.log_jacobian(zp), axis=1)
        total = np.where(np.isfinite(total), total, -np.inf)
        return total if batched else float(total[0])

    def sample_prior(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Draw ``size`` points of ``z`` from the prior; shape ``(size, ndim)``."""
        if int(size) < 1:
            raise ParameterError(f"size must be >= 1, got {size}")
        out = np.empty((int(size), self.ndim))
        for p in self.params:
            x = p.prior.sample(rng, (int(size), p.size))
            out[:, self.slice_of(p.name)] = p.transform.forward(x)
        return out

    def prior_scale_z(self, z: np.ndarray) -> np.ndarray:
        """Per-element width of the prior in ``z`` near ``z`` (for initial spreads)."""
        z = np.asarray(z, dtype=float)
        out = np.empty(self.ndim)
        for p in self.params:
            sl = self.slice_of(p.name)
            dxdz = np.exp(p.transform.log_jacobian(z[sl]))
            out[sl] = p.prior.scale() / np.maximum(dxdz, 1e-300)
        return out

    # ----------------------------------------------------------------- editing
    def fix(self, name: str, value: Any) -> ParamSpace:
        """A new space with free parameter ``name`` held at ``value``."""
        p = self[name]
        if name not in self.names:
            raise ParameterError(f"parameter {name!r} is already fixed")
        arr = p.check_value(value)
        return ParamSpace(
            tuple(q for q in self.params if q.name != name),
            {**self.fixed, name: arr},
            (*self.fixed_params, p),
        )

    def free(self, name: str) -> ParamSpace:
        """A new space in which fixed parameter ``name`` is sampled again (appended)."""
        if name not in self.fixed:
            raise ParameterError(f"parameter {name!r} is not fixed; fixed: {list(self.fixed)}")
        p = self[name]
        return ParamSpace(
            (*self.params, p),
            {k: v for k, v in self.fixed.items() if k != name},
            tuple(q for q in self.fixed_params if q.name != name),
        )

    def replace(self, name: str, **changes: Any) -> ParamSpace:
        """A new space with parameter ``name`` re-declared (e.g. ``prior=Normal(0, 1)``).

        Accepted fields: ``prior``, ``transform``, ``unit``, ``description``. A new
        prior without an explicit transform gets the prior's default transform.
        """
        allowed = {"prior", "transform", "unit", "description"}
        bad = set(changes) - allowed
        if bad:
            raise ParameterError(f"cannot replace fields {sorted(bad)}; allowed {sorted(allowed)}")
        if "prior" in changes and "transform" not in changes:
            changes["transform"] = None
        old = self[name]
        new = replace(old, **changes)
        if name in self.fixed:
            new.check_value(self.fixed[name])
            return ParamSpace(self.params, self.fixed,
                              tuple(new if q.name == name else q for q in self.fixed_params))
        return ParamSpace(tuple(new if q.name == name else q for q in self.params),
                          self.fixed, self.fixed_params)

    def prefixed(self, namespace: str) -> ParamSpace:
        """The same space with every name written ``namespace.name``."""
        if not namespace or "." in namespace:
            raise ParameterError(f"namespace must be a non-empty name without '.': {namespace!r}")

        def ren(p: Param) -> Param:
            return replace(p, name=f"{namespace}.{p.name}")

        return ParamSpace(
            tuple(ren(p) for p in self.params),
            {f"{namespace}.{k}": v for k, v in self.fixed.items()},
            tuple(ren(p) for p in self.fixed_params),
        )

    @staticmethod
    def concat(spaces: Mapping[str, ParamSpace] | Iterable[ParamSpace]) -> ParamSpace:
        """Join spaces; a mapping ``{namespace: space}`` prefixes each one's names."""
        if isinstance(spaces, Mapping):
            spaces = [s.prefixed(ns) for ns, s in spaces.items()]
        params: list[Param] = []
        fixed: dict[str, np.ndarray] = {}
        fixed_params: list[Param] = []
        for s in spaces:
            params.extend(s.params)
            fixed.update(s.fixed)
            fixed_params.extend(s.fixed_params)
        return ParamSpace(tuple(params), fixed, tuple(fixed_params))

    @staticmethod
    def sub_theta(theta: Mapping[str, Any], namespace: str) -> dict[str, Any]:
        """The entries of ``theta`` under ``namespace.``, with the prefix removed."""
        pre = namespace + "."
        return {k[len(pre):]: v for k, v in theta.items() if k.startswith(pre)}

    def __str__(self) -> str:
        rows = [("name", "shape", "unit", "prior", "description")]
        for p in self.params:
            rows.append((p.name, str(p.shape or "()"), p.unit, str(p.prior), p.description))
        for p in self.fixed_params:
            v = self.fixed[p.name]
            val = f"fixed = {np.array2string(v, precision=4, threshold=6)}"
            rows.append((p.name, str(p.shape or "()"), p.unit, val, p.description))
        widths = [min(max(len(r[i]) for r in rows), 48) for i in range(4)]
        lines = [
            "  ".join(c[:w].ljust(w) for c, w in zip(r[:4], widths, strict=True)) + "  " + r[4]
            for r in rows
        ]
        head = f"ParamSpace: {len(self.params)} free ({self.ndim} in z), {len(self.fixed)} fixed"
        return "\n".join([head, *lines])
