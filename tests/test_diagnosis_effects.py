"""Candidate effects of the residual diagnosis (bayeshyst.diagnosis.effects).

Oracles: the score regressors are derivatives of the augmented model's output with
respect to the added block's parameters at their null values, so they must equal
finite differences of the *Composite* (simulated from the input ``u``, not from the
block alone) — exact for blocks linear in their parameters and for the delay inside
its first interpolation interval; closed forms (``s w``, ``s``, ``h x^2``,
``-(w_k - w_{k-1}) / dt``); the derivatives of a sine and the exact response of the
central-difference stencils to it; the Taylor expansion of a second-order system; the
block lists and spec strings of the models the effects augment.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayeshyst.data.excitation import sine
from bayeshyst.data.record import Record
from bayeshyst.diagnosis.catalogue import EFFECTS, get_effect
from bayeshyst.diagnosis.effects import (
    Asymmetry,
    ColoredNoise,
    CreepEffect,
    DelayEffect,
    DriftEffect,
    RateDependence,
    RecordSignals,
    shortest_half_period,
)
from bayeshyst.errors import ModelError
from bayeshyst.models import get
from bayeshyst.models.compose import Composite

BASE_SPEC = "pi_play(n_operators=3)"
FS, F0 = 2000.0, 2.0
DT = 1.0 / FS


def _setup():
    base = get(BASE_SPEC)
    t, u = sine(F0, FS, cycles=3)
    probe = Record(t, u, 0.1 * u)
    # r is fixed (thresholds over the input span), p0 and w are free
    space = base.param_space(probe)
    assert set(space.names) == {"p0", "w"} and set(space.fixed) == {"r"}
    theta = {"p0": 0.1, "w": np.array([0.05, 0.03, 0.02]), "r": space.fixed["r"]}
    w = base.simulate(u, t, theta)
    noise = 1e-6 * np.random.default_rng(0).standard_normal(t.size)
    data = Record(t, u, w + noise, metadata={"frequency_hz": F0}, name="sine")
    # the thresholds depend only on u: the data record gives the same ones
    np.testing.assert_array_equal(base.param_space(data).fixed["r"], theta["r"])
    rec = RecordSignals("sine", t, u, w, 0, F0)
    return base, theta, data, rec


BASE, THETA, DATA, REC = _setup()


def _block_params(composite: Composite, data) -> tuple[str, list[str]]:
    """The added block's namespace and its free parameter names (namespaced)."""
    ns = composite.namespaces[-1]
    names = [n for n in composite.param_space(data).names if n.startswith(ns + ".")]
    return ns, names


def _composite_output(composite: Composite, data, block_values: dict) -> np.ndarray:
    space = composite.param_space(data)
    theta = {f"static.{k}": v for k, v in THETA.items() if k in ("p0", "w")}
    theta.update(space.fixed)  # static.r and the block's fixed values from the data
    for n in space.names:
        if not n.startswith("static."):
            theta[n] = np.zeros(space[n].shape)  # the null: the block does nothing
    theta.update(block_values)
    return composite.simulate(DATA.u, DATA.t, theta)


def _fd_columns(composite: Composite, data, h: float, one_sided: bool) -> np.ndarray:
    """Finite differences w.r.t. every element of every free block parameter."""
    _, names = _block_params(composite, data)
    space = composite.param_space(data)
    y0 = _composite_output(composite, data, {})
    cols = []
    for n in names:
        shape = space[n].shape
        for idx in np.ndindex(*shape) if shape else [()]:
            def at(v, n=n, shape=shape, idx=idx):
                arr = np.zeros(shape)
                arr[idx] = v
                return _composite_output(composite, data, {n: arr})
            cols.append((at(h) - y0) / h if one_sided else (at(h) - at(-h)) / (2 * h))
    return np.column_stack(cols)


@pytest.mark.parametrize("effect, h", [(CreepEffect(), 0.01), (DriftEffect(), 0.01),
                                       (Asymmetry(), 0.01)])
def test_linear_block_regressors_are_the_composite_derivative(effect, h):
    comp, lik, _ = effect.augment(BASE, "gaussian", np.zeros(3), DATA)
    assert isinstance(comp, Composite) and lik == "gaussian" and comp.base == BASE
    # at the null the augmented model is the base model
    np.testing.assert_allclose(_composite_output(comp, DATA, {}), REC.w, rtol=1e-12,
                               atol=1e-12)
    x = effect.regressors(REC, DATA)
    fd = _fd_columns(comp, DATA, h, one_sided=False)
    assert x.shape == fd.shape == (REC.t.size, fd.shape[1])
    # linear in the block's parameters: the central difference is exact up to rounding
    # (eps |y| / h ~ 1e-13); atol covers columns that vanish at the first sample
    np.testing.assert_allclose(x, fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
    assert np.all(np.abs(x).max(axis=0) > 0.1)  # no column is trivially zero


def test_creep_regressors_have_the_block_time_constants():
    # closed form of x_j - w for an exactly discretised lag (ZOH on w), per column
    x = CreepEffect().regressors(REC, DATA)
    comp = CreepEffect().augment(BASE, "gaussian", np.zeros(3), DATA)[0]
    tau = comp.param_space(DATA).fixed["creep.tau"]
    w = REC.w
    for j, tj in enumerate(tau):
        a = math.exp(-DT / tj)
        lag = np.empty_like(w)
        lag[0] = w[0]
        for k in range(1, w.size):
            lag[k] = a * lag[k - 1] + (1 - a) * w[k - 1]
        np.testing.assert_allclose(x[:, j], lag - w, rtol=1e-6,
                                   atol=1e-9 * np.abs(w).max())


def test_drift_and_asymmetry_regressors_in_closed_form():
    s = (REC.t - REC.t[0]) / (REC.t[-1] - REC.t[0])
    np.testing.assert_allclose(DriftEffect().regressors(REC, DATA),
                               np.column_stack([s * REC.w, s]), rtol=1e-9, atol=1e-12)
    lo, hi = float(DATA.y.min()), float(DATA.y.max())
    c, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    np.testing.assert_allclose(Asymmetry().regressors(REC, DATA)[:, 0],
                               half * ((REC.w - c) / half) ** 2, rtol=1e-9,
                               atol=1e-12 * half)


@pytest.mark.parametrize("frac", [0.1, 0.25, 0.6])
def test_delay_regressor_is_the_one_sided_composite_derivative(frac):
    effect = DelayEffect()
    comp = effect.augment(BASE, "gaussian", np.array([0.0]), DATA)[0]
    assert _block_params(comp, DATA)[1] == ["delay.d"]
    x = effect.regressors(REC, DATA)
    # d = 0 is the edge of the prior: one-sided; linear interpolation makes y linear in
    # d on [0, dt], so any step inside the first interval is exact up to rounding
    fd = _fd_columns(comp, DATA, frac * DT, one_sided=True)
    np.testing.assert_allclose(x, fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
    # closed form: minus the backward difference (the history before t0 holds w[0])
    back = -np.diff(REC.w, prepend=REC.w[0]) / DT
    np.testing.assert_allclose(x[:, 0], back, rtol=1e-6, atol=1e-9 * np.abs(back).max())


def test_rate_dependence_regressors_are_the_derivatives_of_a_sine():
    fs, f, amp = 2000.0, 50.0, 3.0
    t = np.arange(400) / fs
    om, dt = 2 * np.pi * f, 1 / fs
    w = amp * np.sin(om * t)
    rec = RecordSignals("s", t, np.zeros_like(t), w, 0, f)
    x = RateDependence().regressors(rec, None)
    inner = slice(2, t.size - 2)  # both stencils central (np.gradient is one-sided at ends)
    d1, d2 = amp * om * np.cos(om * t), -amp * om ** 2 * np.sin(om * t)
    # central differences of a sine: d1 * sinc(om dt), d2 * sinc(om dt)^2, so the
    # errors are bounded by (om dt)^2 / 6 and (om dt)^2 / 3 of the amplitudes (0.4 %,
    # 0.8 % here)
    eps = (om * dt) ** 2
    assert np.max(np.abs(x[inner, 0] - d1[inner])) <= eps / 6 * amp * om
    assert np.max(np.abs(x[inner, 1] - d2[inner])) <= eps / 3 * amp * om ** 2
    sinc = math.sin(om * dt) / (om * dt)
    np.testing.assert_allclose(x[inner, 0], sinc * d1[inner], rtol=0,
                               atol=1e-9 * amp * om)
    np.testing.assert_allclose(x[inner, 1], sinc ** 2 * d2[inner], rtol=0,
                               atol=1e-9 * amp * om ** 2)


def test_rate_dependence_reads_a_resonance_from_its_expansion():
    fn, zeta = 1500.0, 0.07
    wn = 2 * math.pi * fn
    # G(s) = 1 / (1 + 2 zeta s/wn + (s/wn)^2) = 1 - (2 zeta / wn) s - (1 - 4 zeta^2) s^2/wn^2
    a, b = -2 * zeta / wn, -(1 - 4 * zeta ** 2) / wn ** 2
    se_b = abs(b) / 20.0
    out = RateDependence().interpret(np.array([a, b]), np.diag([1e-12, se_b ** 2]), None)
    # interpret drops the 4 zeta^2 term: wn' = wn / sqrt(1 - 4 zeta^2), zeta' = zeta same
    g = 1 / math.sqrt(1 - 4 * zeta ** 2)
    np.testing.assert_allclose(out["natural_frequency_hz"], fn * g, rtol=1e-12)
    np.testing.assert_allclose(out["damping_ratio"], zeta * g, rtol=1e-12)
    # ... which is within 4 zeta^2 = 2 % of the truth (1/sqrt(1-x) - 1 <= x for x <= 0.75)
    assert abs(out["natural_frequency_hz"] / fn - 1) <= 4 * zeta ** 2
    assert abs(out["damping_ratio"] / zeta - 1) <= 4 * zeta ** 2
    np.testing.assert_allclose(out["first_order_time_s"], -a, rtol=1e-15)
    np.testing.assert_allclose(out["curvature_z"], -20.0, rtol=1e-12)
    # b >= 0 is no resonance: no frequency is read
    lag = RateDependence().interpret(np.array([a, abs(b)]), np.diag([1e-12, se_b ** 2]),
                                     None)
    assert "natural_frequency_hz" not in lag and lag["curvature_z"] > 0


# ----------------------------------------------------------------- not_applicable
@pytest.mark.parametrize("spec, effect", [
    ("pi_play+creep", "creep"),
    ("pi_play+creep_fractional", "creep"),
    ("pi_play+second_order", "rate_dependence"),
    ("pi_play+arx", "rate_dependence"),
    ("pi_play+asym_output", "asymmetry"),
    ("pi_play+drift", "drift"),
    ("pi_play+delay", "delay"),
])
def test_effects_a_model_already_has_are_skipped(spec, effect):
    model = get(spec)
    why = EFFECTS[effect].not_applicable(model, "gaussian")
    assert why is not None and spec.split("+")[1] in why
    # every other structural effect is still tested
    for other in set(EFFECTS) - {effect}:
        if other == "creep" and "creep" in spec:
            continue
        assert EFFECTS[other].not_applicable(model, "gaussian") is None


def test_colored_noise_is_skipped_only_for_an_ar1_likelihood():
    assert "AR(1)" in ColoredNoise().not_applicable(get("pi_play"), "ar1")
    assert ColoredNoise().not_applicable(get("pi_play"), "gaussian") is None


def test_nothing_is_skipped_for_the_plain_model():
    assert [n for n, e in EFFECTS.items() if e.not_applicable(get("pi_play"), "gaussian")] \
        == []


def test_get_effect_names_the_valid_effects():
    assert get_effect("drift") is EFFECTS["drift"]
    assert list(EFFECTS) == ["creep", "rate_dependence", "asymmetry", "drift", "delay",
                             "aux", "change_point", "colored_noise"]
    with pytest.raises(ModelError) as err:
        get_effect("nope")
    for name in EFFECTS:
        assert name in str(err.value)


# ------------------------------------------------------------------------ augment
@pytest.mark.parametrize("name, coef, block, suffix", [
    ("creep", np.full(3, 0.01), "creep", "+creep"),
    ("rate_dependence", np.array([-1e-4, -1e-8]), "second_order", "+second_order"),
    ("asymmetry", np.array([0.05]), "asym_output", "+asym_output(order=2)"),
    ("drift", np.array([0.01, 0.1]), "drift", "+drift"),
    ("delay", np.array([3 * DT]), "delay", "+delay(max_delay_samples=10)"),
])
def test_augment_appends_the_effects_block(name, coef, block, suffix):
    model, lik, spec = EFFECTS[name].augment(BASE, "gaussian", coef, DATA)
    assert model.name == f"pi_play+{block}" and model.name.endswith("+" + block)
    assert lik == "gaussian" and spec == suffix
    # the suffix is a spec string rebuilding the same model
    assert get(BASE_SPEC + spec) == model
    # a second effect stacks on the first (the diagnosis loop augments repeatedly)
    again, _, _ = EFFECTS[name].augment(model, "gaussian", coef, DATA)
    assert again.name == f"pi_play+{block}+{block}"


def test_the_output_map_goes_before_linear_blocks_and_leaves_them_linear():
    # Hammerstein order: asymmetry added to a model with creep and a delay goes right
    # after the base; the spec, with the suffix inserted after the base's spec, rebuilds
    # the same model, and creep's gains stay the exact linear group (an output map after
    # creep would make the composite non-affine and leave nothing linear)
    from bayeshyst.diagnosis.effects import insert_after_base
    from bayeshyst.models import get as get_model

    spec = "bouc_wen+creep+delay(max_delay_samples=10)"
    model = get_model(spec)
    assert model.linear_params == ("creep.c",)
    new, _, suffix = Asymmetry().augment(model, "gaussian", np.array([0.05]), DATA)
    assert [b.name for b in new.blocks] == ["asym_output", "creep", "delay"]
    new_spec = insert_after_base(spec, suffix)
    assert new_spec == "bouc_wen+asym_output(order=2)+creep+delay(max_delay_samples=10)"
    assert get_model(new_spec) == new and new.linear_params == ("creep.c",)
    # a base alone, or a base whose blocks are not all affine: appended
    assert Asymmetry().augment(get_model("bouc_wen"), "gaussian", np.array([0.05]),
                               DATA)[0].name == "bouc_wen+asym_output"
    assert insert_after_base("pi_play(n_operators=8)", "+creep") == \
        "pi_play(n_operators=8)+creep"


def test_augment_with_colored_noise_changes_only_the_likelihood():
    model, lik, spec = ColoredNoise().augment(BASE, "gaussian", np.array([0.4]), DATA)
    assert model is BASE and lik == "ar1" and spec == " with likelihood ar1"


@pytest.mark.parametrize("coef", [7.3 * DT, -7.3 * DT])
def test_delay_history_covers_three_times_the_estimate(coef):
    model, _, spec = DelayEffect().augment(BASE, "gaussian", np.array([coef]), DATA)
    blk = model.blocks[-1]
    # ceil(3 * 7.3) = 22 samples of history; the prior's top reaches 3 |d|
    assert blk.max_delay_samples == 22 and spec == "+delay(max_delay_samples=22)"
    top = model.param_space(DATA)["delay.d"].prior.upper
    assert top >= 3 * abs(coef)
    # a small estimate keeps the default history of 10 samples
    small = DelayEffect().augment(BASE, "gaussian", np.array([0.5 * DT]), DATA)[0]
    assert small.blocks[-1].max_delay_samples == 10


def test_delay_room_stops_at_half_the_shortest_period():
    # a score estimate of 0.2 s on a 2 Hz record: three times it (0.6 s) reaches past half
    # a period (0.25 s = 500 samples at 2 kHz), where the delayed loop's phase wraps
    model = DelayEffect().augment(BASE, "gaussian", np.array([0.2]), DATA)[0]
    assert model.blocks[-1].max_delay_samples == round(0.5 / F0 / DT)
    assert math.isclose(shortest_half_period(DATA), 0.5 / F0)
    # without a declared frequency the period comes from the input's reversals, also
    # through sensor noise on the input (0.1 % of its span flips du's sign at every sample)
    rng = np.random.default_rng(3)
    noisy = Record(DATA.t, DATA.u + 1e-3 * np.ptp(DATA.u) * rng.standard_normal(DATA.n),
                   DATA.y, name="no frequency")
    assert abs(shortest_half_period(noisy) - 0.5 / F0) < 5 * DT
    blk = DelayEffect().augment(BASE, "gaussian", np.array([0.2]), noisy)[0].blocks[-1]
    assert abs(blk.max_delay_samples - 0.5 / F0 / DT) <= 5
    # a record with fewer than two reversals has no period: the estimate alone sizes it
    ramp = Record(DATA.t, DATA.t.copy(), DATA.t.copy(), name="ramp")
    assert shortest_half_period(ramp) is None
    blk = DelayEffect().augment(BASE, "gaussian", np.array([0.2]), ramp)[0].blocks[-1]
    assert blk.max_delay_samples == math.ceil(0.6 / DT)


# ------------------------------------------------------- effects with several variants
def test_aux_and_change_point_regressors_are_their_blocks_derivatives():
    # the score regressors are d y / d (g, h) of the block at g = h = 0, per variant
    from bayeshyst.data.dataset import Dataset
    from bayeshyst.diagnosis.driven import AuxEffect, ChangePointEffect
    from bayeshyst.models.blocks import AuxInput, ChangePoint

    rec = DATA if isinstance(DATA, Record) else DATA[0]
    temp = 20 + 3 * np.sin(np.linspace(0, 3, rec.n))
    rec = rec.with_(covariates={"temperature_c": temp})
    data = Dataset((rec,))
    w = np.sin(np.linspace(0, 20, rec.n))
    sig = RecordSignals(rec.name, rec.t, rec.u, w, rec.scored.start or 0, None)
    (label, x, _), = AuxEffect().variants([sig], data, BASE)
    assert label == "temperature_c"
    blk = AuxInput(column="temperature_c")
    fixed = blk.param_space(data).fixed
    h = 1e-6
    for j, name in enumerate(("g", "h")):
        theta = {**fixed, "g": np.zeros(1), "h": np.zeros(1)}
        theta[name] = np.array([h])
        y = blk.apply(w, rec.t, theta, covariates={"temperature_c": temp}).y
        np.testing.assert_allclose((y - w)[sig.s0:] / h, x[:, j], rtol=1e-6, atol=1e-9)
    variants = ChangePointEffect().variants([sig], data, BASE)
    label, x, _ = variants[len(variants) // 2]
    cp = ChangePoint()
    theta = {**cp.param_space(data).fixed, "t_c": float(label), "g": h, "h": 0.0}
    y = cp.apply(w, rec.t, theta).y
    np.testing.assert_allclose((y - w)[sig.s0:] / h, x[:, 0], rtol=1e-4, atol=1e-9)
    # augmenting names the column and rebuilds from its spec
    model, _, suffix = AuxEffect().augment(BASE, "gaussian", np.zeros(2), data,
                                           variant="temperature_c")
    assert suffix == "+aux(column='temperature_c')"
    assert get(BASE_SPEC + suffix) == model
