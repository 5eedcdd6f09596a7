"""Composed models: a hysteresis model followed by effect blocks (MODELS.md §7).

``Composite(base, blocks)`` feeds the base model's output ``w = H[u]`` through the
blocks in order, ``y = B_n[... B_1[w]]``: with linear dynamics after a static
hysteresis this is the Hammerstein model of review §10 (Eq. 56–57); with creep, drift,
delay or an output map it adds those effects to any base model. Spec strings name the
same thing in one word: ``"bouc_wen+second_order+creep"`` (:func:`parse_spec`, which
:func:`bayeshyst.models.get` calls for every spec containing ``+``).

Parameters are namespaced: the base's under ``static.`` and each block's under its
name (``static.w``, ``arx.kappa``, ``creep.c``); a block that appears twice gets
``name_2`` for its second occurrence.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bayeshyst.errors import ModelError, ParameterError
from bayeshyst.models import registry
from bayeshyst.models.base import (
    HysteresisModel,
    LinearDesign,
    LinearInParams,
    check_covariates,
    unit_signals,
)
from bayeshyst.models.blocks import Creep, EffectBlock, block_class, block_names
from bayeshyst.params import ParamSpace

__all__ = ["Composite", "Hammerstein", "WithCreep", "block_names", "block_namespaces",
           "leading_part", "model_spec", "parse_spec"]

#: Namespace of the base model's parameters.
STATIC = "static"


def block_namespaces(blocks: Sequence[EffectBlock]) -> tuple[str, ...]:
    """The parameter namespace of each block: its name, ``name_2`` for a second one."""
    seen: dict[str, int] = {}
    out = []
    for b in blocks:
        seen[b.name] = seen.get(b.name, 0) + 1
        out.append(b.name if seen[b.name] == 1 else f"{b.name}_{seen[b.name]}")
    return tuple(out)


@dataclass(frozen=True)
class Composite(LinearInParams, HysteresisModel):
    """A base hysteresis model followed by effect blocks, itself a :class:`HysteresisModel`.

    Parameters
    ----------
    base : HysteresisModel
        The static (or any) hysteresis model ``u -> w``. A Composite given as base is
        flattened: its blocks come first.
    blocks : EffectBlock or sequence of EffectBlock
        Applied in order to the base output.

    Notes
    -----
    ``name`` is the spec string (``"pi_play+second_order+creep"``); ``rate_dependent``
    holds if any part is. The state is the base state followed by each block's state
    (block sizes are structural; the base's is the remainder). The relaxed initial
    state is the base's relaxed state at ``u0`` and each block at its steady state for
    the output of the part before it at ``u0``, so a record starts at rest.

    Linearity: when the base is linear in some parameters (:class:`LinearInParams`) and
    every block is affine in its input (``EffectBlock.affine``: linear dynamics, creep,
    delay, drift), the composite is linear in the base's linear parameters
    (``static.<name>``), with ``Phi`` the base's columns passed through the blocks
    (:meth:`linear_design`). An output map (``asym_output``) breaks that. A block that is
    linear in its own parameters (``unexplained``) offers its coefficients instead;
    :attr:`linear_group` takes the larger of the two groups.
    """

    base: HysteresisModel
    blocks: tuple[EffectBlock, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.base, HysteresisModel):
            raise ModelError(f"Composite base must be a HysteresisModel, got {self.base!r}")
        blocks = self.blocks
        blocks = (blocks,) if isinstance(blocks, EffectBlock) else tuple(blocks)
        bad = [b for b in blocks if not isinstance(b, EffectBlock)]
        if bad:
            raise ModelError(f"Composite blocks must be EffectBlocks (valid: "
                             f"{', '.join(block_names())}), got {bad[0]!r}")
        base = self.base
        if isinstance(base, Composite):
            base, blocks = base.base, base.blocks + blocks
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "blocks", blocks)

    # the registry name and flags of a composed model follow from its parts
    @property
    def name(self) -> str:  # type: ignore[override]
        """The spec string: base and block names joined by ``+``."""
        return "+".join([self.base.name, *(b.name for b in self.blocks)])

    @property
    def rate_dependent(self) -> bool:  # type: ignore[override]
        """Whether the base or any block is rate-dependent."""
        return self.base.rate_dependent or any(b.rate_dependent for b in self.blocks)

    @property
    def has_output_offset(self) -> bool:  # type: ignore[override]
        """Whether the base has an output offset of its own (the blocks pass it on).

        Every block maps a constant input to a constant output, so an offset of the
        base is still one after them; a second, observation offset would be an exact
        non-identifiability (a ridge the sampler cannot converge along).
        """
        return self.base.has_output_offset

    @property
    def multimodal_posterior(self) -> bool:  # type: ignore[override]
        """Whether the base is known to give a minor posterior mode."""
        return self.base.multimodal_posterior

    @property
    def equation(self) -> str:  # type: ignore[override]
        """The non-empty equations of the base and the blocks, joined by ``->``."""
        parts = [self.base.equation, *(b.equation for b in self.blocks)]
        return " -> ".join(p for p in parts if p)

    @property
    def linear_params(self) -> tuple[str, ...]:  # type: ignore[override]
        """The parameters the sampler draws exactly (see :meth:`linear_group`)."""
        return self.linear_group[1]

    @functools.cached_property
    def linear_group(self) -> tuple[int | None, tuple[str, ...]]:
        """Where the composite's linear block lies, and its (namespaced) parameters.

        Two kinds of group qualify: the base's linear parameters (``static.`` names)
        when every block is affine in its input, and a block's own linear parameters
        (:attr:`EffectBlock.linear_params`: the ``unexplained`` term's coefficients,
        linear given the block's input) when every block after it is affine. They do
        not combine -- the base's output is the block's input, so the two are bilinear
        -- and the larger group is taken (ties: the base), because the ensemble moves
        sample what is left: Bouc–Wen's one gain ``k`` is better left to them than the
        twelve coefficients of a smooth term.

        Returns
        -------
        (int or None, tuple of str)
            ``-1`` for the base, a block index, or None and ``()`` when nothing is
            linear.
        """
        groups = []
        base_lin = tuple(getattr(self.base, "linear_params", ()))
        if base_lin and hasattr(self.base, "linear_design") \
                and all(b.affine for b in self.blocks):
            shapes = self.base._shapes
            size = sum(int(np.prod(shapes[n], dtype=int)) for n in base_lin)
            groups.append((size, -1, tuple(f"{STATIC}.{n}" for n in base_lin)))
        for i, (ns, block) in enumerate(zip(self.namespaces, self.blocks, strict=True)):
            if block.linear_params and all(b.affine for b in self.blocks[i + 1:]):
                size = sum(int(np.prod(block._shapes[n], dtype=int))
                           for n in block.linear_params)
                groups.append((size, i, tuple(f"{ns}.{n}" for n in block.linear_params)))
        if not groups:
            return None, ()
        best = max(groups, key=lambda g: g[0])  # the first of the largest: base on a tie
        return best[1], best[2]

    @property
    def linear_affine(self) -> bool:  # type: ignore[override]
        """Blocks such as drift add a term that does not scale with the input."""
        return True

    def linear_design(self, u: Any, t: Any, thetas: Mapping[str, Any],
                      names: tuple[str, ...] | None = None, *,
                      covariates: Mapping[str, Any] | None = None) -> LinearDesign:
        """``Phi`` and ``c`` of ``W`` parameter vectors for the linear group's parameters.

        See :meth:`LinearInParams.linear_design`. For the base's group: the base's design
        passed through the blocks (:meth:`apply_blocks_to_design`). For a block's group:
        the part before the block is simulated once per walker, the block applied with
        each unit coefficient vector and with none (``W (P + 1)`` signals), and the
        columns passed through the blocks after it. ``covariates`` as in :meth:`run`.
        """
        where, group = self.linear_group
        names = group if names is None else tuple(names)
        bad = [n for n in names if n not in group]
        if bad or not names:
            raise ParameterError(f"{self.name}: {list(names)} are not linear parameters; "
                                 f"linear: {list(group)}")
        if where == -1:
            base_theta, _ = self._split(thetas)
            base_names = tuple(n[len(STATIC) + 1:] for n in names)
            # a base that reads a measured column (pi_covariate) gets it
            base = self.base.linear_design(u, t, base_theta, base_names,
                                           covariates=covariates)
            return self.apply_blocks_to_design(base, t, thetas, names, covariates=covariates)
        return self._block_design(where, u, t, thetas, names, covariates)

    def _block_design(self, where: int, u: Any, t: Any, thetas: Mapping[str, Any],
                      names: tuple[str, ...], covariates: Mapping[str, Any] | None
                      ) -> LinearDesign:
        block, ns = self.blocks[where], self.namespaces[where]
        head, head_theta = leading_part(self, where, thetas)
        traj = head.run_batch(u, t, head_theta, covariates=covariates)
        width, n = traj.y.shape
        t = np.ascontiguousarray(t, dtype=np.float64)
        cov = check_covariates(covariates, self.covariates, n, self.name)
        own = [nm[len(ns) + 1:] for nm in names]
        p = sum(int(np.prod(block._shapes[nm], dtype=int)) for nm in own)
        n_sig = p + 1  # each unit vector, then beta = 0 (the block's const)
        _, block_thetas = self._split(thetas)
        rest = {k: np.broadcast_to(np.asarray(v, dtype=np.float64),
                                   (width, *np.shape(v)[1:]))
                for k, v in block_thetas[where].items() if k not in own}
        direct = block._linear_columns(np.nan_to_num(traj.y), t, rest, tuple(own), cov)
        if direct is not None:
            phi, const, f = direct
            design = LinearDesign(tuple(names), np.ascontiguousarray(phi),
                                  np.ascontiguousarray(const),
                                  traj.failed | np.asarray(f, dtype=bool))
            return self._through(design, t, thetas, where + 1, cov)
        rep = {k: _walker_major(v, width, n_sig)
               for k, v in block_thetas[where].items() if k not in own}
        rep.update(unit_signals(tuple(own), block._shapes, width, n_sig))
        # a failed head gives NaN rows; the block flags them failed, the design keeps them
        w = np.repeat(np.nan_to_num(traj.y), n_sig, axis=0)
        s0 = block._initial_state(rep, np.ascontiguousarray(w[:, 0]), math.nan)
        out, _, f = block._apply_with(np.ascontiguousarray(w), t, rep, s0, cov)
        out = np.asarray(out).reshape(width, n_sig, n)
        failed = traj.failed | np.asarray(f, dtype=bool).reshape(width, n_sig).any(axis=1)
        const = out[:, p]
        phi = (out[:, :p] - const[:, None, :]).transpose(0, 2, 1)
        design = LinearDesign(tuple(names), np.ascontiguousarray(phi),
                              np.ascontiguousarray(const), failed)
        return self._through(design, t, thetas, where + 1, cov)

    def apply_blocks_to_design(self, base: LinearDesign, t: Any, thetas: Mapping[str, Any],
                               names: tuple[str, ...], *,
                               covariates: Mapping[str, Any] | None = None) -> LinearDesign:
        """Pass a base design through the blocks: ``B[const]``, ``B[phi_j] - B[0]``.

        Exact for affine blocks: ``B[sum_j b_j phi_j + c] = sum_j b_j (B[phi_j] - B[0])
        + B[c]``, each signal starting from its own steady state (the steady state is
        linear in the held input, so the superposition holds from the first sample).

        Parameters
        ----------
        base : LinearDesign
            The base model's design (``phi`` (1 or W, N, P), ``const``).
        t : array_like, shape (N,)
            Sample times (s).
        thetas : mapping
            Every parameter of the composite, batched (the blocks' are used).
        names : tuple of str
            ``static.`` names of the columns.
        covariates : mapping of str to array_like, optional
            Measured channels ``column -> (N,)`` the blocks read (None: nominal).
        """
        if not all(b.affine for b in self.blocks):
            raise ModelError(f"{self.name}: a block is not affine in its input")
        t = np.ascontiguousarray(t, dtype=np.float64)
        covariates = check_covariates(covariates, self.covariates, t.size, self.name)
        design = LinearDesign(tuple(names), base.phi, base.const, base.failed)
        return self._through(design, t, thetas, 0, covariates)

    def _through(self, design: LinearDesign, t: np.ndarray, thetas: Mapping[str, Any],
                 first: int, covariates: dict[str, np.ndarray] | None) -> LinearDesign:
        """``design`` passed through the (affine) blocks from index ``first`` on."""
        if first >= len(self.blocks):
            return design
        _, block_thetas = self._split(thetas)
        widths = [int(np.shape(v)[0]) for v in thetas.values()]
        width = max([*widths, design.phi.shape[0], design.const.shape[0]])
        p = design.phi.shape[2]
        n = design.phi.shape[1]
        n_sig = p + 2  # const, the columns, zero (B[0] for blocks with an offset term)
        sig = np.zeros((width, n_sig, n))
        sig[:, 0] = design.const
        sig[:, 1:p + 1] = design.phi.transpose(0, 2, 1)
        w = np.ascontiguousarray(sig.reshape(width * n_sig, n))
        failed = np.broadcast_to(design.failed, (width,)).copy()
        for block, th in zip(self.blocks[first:], block_thetas[first:], strict=True):
            rep = {k: _walker_major(v, width, n_sig) for k, v in th.items()}
            s0 = block._initial_state(rep, np.ascontiguousarray(w[:, 0]), math.nan)
            w, _, f = block._apply_with(w, t, rep, s0, covariates)
            w = np.ascontiguousarray(w)
            failed |= np.asarray(f, dtype=bool).reshape(width, n_sig).any(axis=1)
        out = w.reshape(width, n_sig, n)
        phi = out[:, 1:p + 1] - out[:, n_sig - 1:n_sig]
        return LinearDesign(design.names, np.ascontiguousarray(phi.transpose(0, 2, 1)),
                            np.ascontiguousarray(out[:, 0]), failed)

    @property
    def namespaces(self) -> tuple[str, ...]:
        """Parameter namespaces of the blocks, in order (``"creep"``, ``"creep_2"``)."""
        return block_namespaces(self.blocks)

    def param_space(self, data: Any = None) -> ParamSpace:
        """The base's space under ``static.`` and each block's under its namespace.

        ``data`` as in :meth:`HysteresisModel.param_space`; every part scales its priors
        from it.
        """
        spaces = {STATIC: self.base.param_space(data)}
        for ns, block in zip(self.namespaces, self.blocks, strict=True):
            spaces[ns] = block.param_space(data)
        return ParamSpace.concat(spaces)

    def _split(self, theta: Mapping[str, np.ndarray]) -> tuple[dict, list[dict]]:
        return (ParamSpace.sub_theta(theta, STATIC),
                [ParamSpace.sub_theta(theta, ns) for ns in self.namespaces])

    def _initial_state(self, theta: Mapping[str, np.ndarray], u0: float) -> np.ndarray:
        return self._initial_state_with(theta, u0, None)

    def _initial_state_with(self, theta: Mapping[str, np.ndarray], u0: float,
                            covariates: Mapping[str, np.ndarray] | None) -> np.ndarray:
        base_theta, block_thetas = self._split(theta)
        s_base = self.base._initial_state_with(base_theta, u0, covariates)
        # the measured columns at the first sample: the blocks rest at the output the
        # parts give there (what the linear design's signals start from too)
        first = None if covariates is None else {k: v[:1] for k, v in covariates.items()}
        # the base's output at rest: one sample at u0 from a copy of its relaxed state
        w, _, _ = self.base._run_with(np.array([float(u0)]), np.zeros(1), base_theta,
                                      np.array(s_base, dtype=np.float64, order="C"), first)
        w0 = np.ascontiguousarray(w[:, 0])
        states = [np.asarray(s_base, dtype=np.float64)]
        for i, (block, th) in enumerate(zip(self.blocks, block_thetas, strict=True)):
            s = block._initial_state(th, w0, math.nan)
            states.append(s)
            if i + 1 < len(self.blocks):
                # the next block rests at this block's steady output for w0
                out, _, _ = block._apply_with(np.ascontiguousarray(w0[:, None]), np.zeros(1),
                                              th, s, first)
                w0 = np.ascontiguousarray(out[:, 0])
        return np.ascontiguousarray(np.concatenate(states, axis=1))

    @property
    def covariates(self) -> tuple[str, ...]:  # type: ignore[override]
        """Measured columns the base and the blocks read, in order of first use."""
        return tuple(dict.fromkeys(c for part in (self.base, *self.blocks)
                                   for c in part.covariates))

    def _run(self, u, t, theta, state0):
        return self._run_with(u, t, theta, state0, None)

    def _run_with(self, u, t, theta, state0, covariates):
        base_theta, block_thetas = self._split(theta)
        sizes = [b.state_size for b in self.blocks]
        n_base = state0.shape[1] - sum(sizes)
        if n_base < 0:
            raise ParameterError(f"{self.name}: state0 has {state0.shape[1]} entries, the "
                                 f"blocks alone need {sum(sizes)}")
        w, s_base, failed = self.base._run_with(u, t, base_theta,
                                                np.ascontiguousarray(state0[:, :n_base]),
                                                covariates)
        failed = np.array(failed, dtype=bool)
        states = [s_base]
        start = n_base
        for block, th, size in zip(self.blocks, block_thetas, sizes, strict=True):
            s0 = np.ascontiguousarray(state0[:, start:start + size])
            w, s, f = block._apply_with(np.ascontiguousarray(w), t, th, s0, covariates)
            failed |= f
            states.append(s)
            start += size
        return w, np.ascontiguousarray(np.concatenate(states, axis=1)), failed

    def __repr__(self) -> str:
        return f"Composite({self.base!r}, {self.blocks!r})"


def _walker_major(value: Any, width: int, n_sig: int) -> np.ndarray:
    """A parameter's ``(W, ...)`` (or broadcastable) values, each repeated ``n_sig`` times."""
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (width, *np.shape(value)[1:]))
    return np.ascontiguousarray(np.repeat(arr, n_sig, axis=0))


def Hammerstein(static: HysteresisModel,  # capitalised: reads as a model name
                dynamics: EffectBlock | Sequence[EffectBlock]) -> Composite:
    """Hammerstein model: static hysteresis ``w = H[u]`` then linear dynamics ``G`` (Eq. 56–57).

    Parameters
    ----------
    static : HysteresisModel
        The rate-independent part (``PrandtlIshlinskii(10)``, ``BoucWen()``, ...).
    dynamics : EffectBlock or sequence of EffectBlock
        Typically :class:`~bayeshyst.models.blocks.ARX` or
        :class:`~bayeshyst.models.blocks.SecondOrder` (unit DC gain).
    """
    return Composite(static, dynamics)


def WithCreep(model: HysteresisModel, n_terms: int = 3, *,
              tau_min: float | None = None, tau_max: float | None = None) -> Composite:
    """``model`` followed by a :class:`~bayeshyst.models.blocks.Creep` bank of ``n_terms`` lags."""
    return Composite(model, (Creep(n_terms, tau_min, tau_max),))


_PART = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*(?:\((.*)\))?$", re.DOTALL)


def _split_part(part: str, spec: str) -> tuple[str, dict[str, Any], list[str]]:
    """``"pi_play(n_operators=4)"`` -> ``("pi_play", {"n_operators": 4}, [])``.

    Positional arguments are model specs (a name, a name with settings, or a quoted
    spec) and come back as their text, for a wrapper model that takes one as its
    ``base``: ``"conditioned(preisach(n_levels=8), column='t')"`` ->
    ``("conditioned", {"column": "t"}, ["preisach(n_levels=8)"])``.
    """
    m = _PART.match(part)
    if m is None:
        raise ModelError(f"model spec {spec!r}: cannot read {part!r}; write a name, optionally "
                         f"with settings: 'pi_play(n_operators=6)+second_order'")
    name, args = m.group(1), m.group(2)
    if args is None or not args.strip():
        return name, {}, []
    source = f"f({args})"
    try:
        call = ast.parse(source, mode="eval").body
    except SyntaxError as exc:
        raise ModelError(f"model spec {spec!r}: settings of {name!r} are not "
                         f"'key=value, ...': {exc.msg}") from None
    if not isinstance(call, ast.Call):
        raise ModelError(f"model spec {spec!r}: settings of {name!r} must be given by name "
                         f"(key=value), got {args!r}")
    positional = []
    for arg in call.args:
        if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
            positional.append(arg.value)
        elif isinstance(arg, ast.Name | ast.Call | ast.BinOp):  # BinOp: 'model+block'
            positional.append(ast.get_source_segment(source, arg) or ast.unparse(arg))
        else:
            raise ModelError(f"model spec {spec!r}: settings of {name!r} must be given by "
                             f"name (key=value); only a wrapper's base model may come first, "
                             f"got {ast.unparse(arg)!r}")
    settings = {}
    for kw in call.keywords:
        if kw.arg is None:
            raise ModelError(f"model spec {spec!r}: '**' is not allowed in settings")
        try:
            settings[kw.arg] = ast.literal_eval(kw.value)
        except ValueError:
            raise ModelError(f"model spec {spec!r}: setting {kw.arg!r} of {name!r} must be a "
                             f"literal (number, string, tuple), got "
                             f"{ast.unparse(kw.value)!r}") from None
    return name, settings, positional


def _top_level_parts(spec: str) -> list[str]:
    """``spec`` split at the ``+`` outside parentheses (a wrapper's base is one part)."""
    parts, depth, start = [], 0, 0
    for i, ch in enumerate(spec):
        depth += (ch == "(") - (ch == ")")
        if ch == "+" and depth == 0:
            parts.append(spec[start:i])
            start = i + 1
    return [*parts, spec[start:]]


def _takes_base(name: str) -> bool:
    """Whether the registered model ``name`` wraps another model (has a ``base`` setting)."""
    try:
        cls = registry.model_class(name)
    except ModelError:
        return False
    return any(f.name == "base" for f in dataclasses.fields(cls) if f.init)


def parse_spec(spec: str) -> HysteresisModel:
    """Build a model from a spec string ``"base+block+block..."``.

    The first part is a registered model name (:func:`bayeshyst.models.registry.get`);
    the others are effect-block names (:func:`block_names`). Each part may carry
    structural settings in parentheses, as literals given by name:
    ``"pi_play(n_operators=6)+second_order"``, ``"preisach(n_levels=8)"``. Without
    them a part has its default settings. A spec without ``+`` is just the model. A
    wrapper model (one with a ``base`` setting, ``conditioned``) takes its base model
    as the one positional argument, itself a spec part:
    ``"conditioned(preisach(n_levels=8), column='load_n')+creep"``.

    Raises
    ------
    ModelError
        For an empty part, a block name in first place, an unknown model or block (the
        message lists the valid names), or settings that are not ``key=literal`` or
        that the model does not have.
    """
    parts = [p.strip() for p in _top_level_parts(str(spec))]
    if any(not p for p in parts):
        raise ModelError(f"model spec {spec!r} has an empty part; write e.g. 'pi_play+arx'")
    (head, head_settings, head_base), *rest = [_split_part(p, spec) for p in parts]
    if head in block_names():
        raise ModelError(f"model spec {spec!r} must start with a hysteresis model "
                         f"({', '.join(registry.names())}), not the effect block {head!r}")
    for name, _, positional in rest:
        if positional:
            raise ModelError(f"model spec {spec!r}: settings of block {name!r} must be given "
                             f"by name (key=value), got {positional[0]!r} first")
    if head_base:
        if not _takes_base(head):
            raise ModelError(f"model spec {spec!r}: settings of {head!r} must be given by "
                             f"name (key=value); only a wrapper such as 'conditioned' takes "
                             f"a model first, got {head_base[0]!r}")
        if len(head_base) > 1 or "base" in head_settings:
            raise ModelError(f"model spec {spec!r}: {head!r} takes one base model, given "
                             f"first or as base=..., not both or several")
        head_settings["base"] = head_base[0]
    base = registry.get(head, **head_settings)
    if not rest:
        return base
    return Composite(base, tuple(registry.build(block_class(n), kw, f"model spec {spec!r}: "
                                                f"block {n!r}") for n, kw, _ in rest))


def _literal(value: Any) -> bool:
    if value is None or isinstance(value, (bool, int, float, str)):
        return not (isinstance(value, float) and not math.isfinite(value))
    return isinstance(value, tuple) and all(_literal(v) for v in value)


def _part_spec(part: Any) -> str:
    """``name(setting=literal, ...)`` with the settings that differ from their defaults."""
    settings = []
    for f in dataclasses.fields(part):
        if not f.init:
            continue
        value = getattr(part, f.name)
        if f.name == "base" and isinstance(value, HysteresisModel):
            # a wrapper's base model comes first, as its own spec (settings included)
            settings.insert(0, _part_spec(value))
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            default = dataclasses.MISSING
        if default is not dataclasses.MISSING and value == default:
            continue
        if not _literal(value):
            raise ModelError(f"{part.name}: setting {f.name}={value!r} cannot be written in a "
                             "spec string (numbers, strings and tuples of them can)")
        settings.append(f"{f.name}={value!r}")
    # the registry name (a wrapper's instance name also says what it wraps)
    name = type(part).name
    return f"{name}({', '.join(settings)})" if settings else name


def leading_part(model: HysteresisModel, n_blocks: int, theta: Mapping[str, Any]
                 ) -> tuple[HysteresisModel, dict[str, Any]]:
    """The base followed by the first ``n_blocks`` blocks of ``model``, with its parameters.

    A sub-composite names its parameters as the full one does (same namespaces), so
    its parameters are ``theta``'s of those namespaces; the bare base (``n_blocks`` 0)
    takes the ``static.`` ones without their namespace. A model that is not a
    :class:`Composite` is its own leading part.
    """
    if not isinstance(model, Composite):
        return model, dict(theta)
    if n_blocks == 0:
        return model.base, ParamSpace.sub_theta(theta, STATIC)
    keep = (STATIC, *block_namespaces(model.blocks)[:n_blocks])
    try:
        head = _head(model, n_blocks)
    except TypeError:  # a model with an unhashable setting: built afresh
        head = Composite(model.base, tuple(model.blocks[:n_blocks]))
    return head, {k: v for k, v in theta.items() if k.split(".", 1)[0] in keep}


@functools.lru_cache(maxsize=64)
def _head(model: Composite, n_blocks: int) -> Composite:
    # one instance per (model, n): a new one per call re-derived its parameter shapes
    # (param_space) on every design the sampler asked for
    return Composite(model.base, tuple(model.blocks[:n_blocks]))


def model_spec(model: HysteresisModel) -> str:
    """The spec string that rebuilds ``model`` with :func:`parse_spec` (settings included).

    ``model.name`` names the parts only (``"pi_play+second_order"``); this carries every
    structural setting that is not its default (``"pi_play(n_operators=8)+second_order"``),
    which is what a saved fit needs to be reloaded as the model that was fitted.

    Raises
    ------
    ModelError
        If a setting is not a literal, or the string does not rebuild an equal model.
    """
    parts = ([model.base, *model.blocks] if isinstance(model, Composite) else [model])
    spec = "+".join(_part_spec(p) for p in parts)
    if registry.get(spec) != model:
        raise ModelError(f"{model.name}: its spec string {spec!r} does not rebuild it")
    return spec


registry.register_spec_parser(parse_spec)
