"""Parameters: transforms, priors and ParamSpace, checked against independent oracles."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from bayeshyst.errors import ParameterError
from bayeshyst.params import (
    HalfNormal,
    Identity,
    LogitTransform,
    LogNormal,
    LogTransform,
    Normal,
    Param,
    ParamSpace,
    ProbitTransform,
    TruncatedNormal,
    Uniform,
    UpperLogTransform,
)

# each prior next to scipy's implementation of the same distribution: the oracle
PRIORS = [
    (Uniform(-2.0, 3.0), stats.uniform(loc=-2.0, scale=5.0)),
    (Normal(1.5, 0.7), stats.norm(1.5, 0.7)),
    (LogNormal(0.3, 0.5), stats.lognorm(s=0.5, scale=math.exp(0.3))),
    (HalfNormal(2.0), stats.halfnorm(scale=2.0)),
    (TruncatedNormal(0.5, 1.0, 0.0, 2.0), stats.truncnorm(-0.5, 1.5, loc=0.5, scale=1.0)),
    (TruncatedNormal(0.0, 1.0, 1.0), stats.truncnorm(1.0, np.inf, loc=0.0, scale=1.0)),
    (TruncatedNormal(3.0, 1.0, -np.inf, 0.0), stats.truncnorm(-np.inf, -3.0, loc=3.0, scale=1.0)),
]
PRIOR_IDS = [type(p).__name__ + str(i) for i, (p, _) in enumerate(PRIORS)]

TRANSFORMS = [Identity(), LogTransform(0.0), LogTransform(-3.0), UpperLogTransform(2.0),
              LogitTransform(-1.0, 4.0)]


@pytest.mark.parametrize(("prior", "ref"), PRIORS, ids=PRIOR_IDS)
def test_logpdf_and_cdf_match_scipy(prior, ref):
    lo, hi = prior.support
    xs = ref.ppf(np.linspace(0.01, 0.99, 41))
    np.testing.assert_allclose(prior.logpdf(xs), ref.logpdf(xs), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(prior.cdf(xs), ref.cdf(xs), rtol=1e-10, atol=1e-12)
    outside = [v for v in (lo - 1.0, hi + 1.0) if math.isfinite(v)]
    if outside:
        assert np.all(prior.logpdf(np.array(outside)) == -np.inf)


@pytest.mark.parametrize(("prior", "ref"), PRIORS, ids=PRIOR_IDS)
def test_prior_samples_follow_the_cdf(prior, ref):
    # Kolmogorov–Smirnov against the prior's own cdf (checked against scipy above); a
    # fixed seed makes this deterministic, and p > 1e-3 is a 0.1 % false-alarm level
    x = prior.sample(np.random.default_rng(7), (4000,))
    assert stats.kstest(x, prior.cdf).pvalue > 1e-3


@pytest.mark.parametrize("tr", TRANSFORMS, ids=lambda t: repr(t))
@given(z=st.floats(-8.0, 8.0))
@settings(max_examples=60, deadline=None)
def test_transform_round_trip_and_jacobian(tr, z):
    _check_round_trip_and_jacobian(tr, z)


def _check_round_trip_and_jacobian(tr, z):
    x = tr.inverse(np.array([z]))
    np.testing.assert_allclose(tr.forward(x), [z], rtol=1e-9, atol=1e-9)
    # log|dx/dz| against a central finite difference of the inverse map
    h = 1e-5
    fd = (tr.inverse(np.array([z + h])) - tr.inverse(np.array([z - h]))) / (2 * h)
    np.testing.assert_allclose(tr.log_jacobian(np.array([z])), np.log(np.abs(fd)), atol=1e-6)


@given(z=st.floats(-4.0, 4.0))
@settings(max_examples=60, deadline=None)
def test_probit_round_trip_and_jacobian(z):
    # |z| <= 4: beyond it, x - lower (or upper - x) is a few ulps of the bounds' scale and
    # the round trip is only as exact as those ulps (the lower-bound-0 case below is not)
    _check_round_trip_and_jacobian(ProbitTransform(-1.0, 4.0), z)


def test_probit_is_the_normal_cdf_and_makes_a_uniform_prior_standard_normal():
    # oracle: scipy's normal cdf; and for x ~ Uniform(a, b), z = Phi^-1((x - a)/(b - a)) is
    # N(0, 1) exactly, so log p(x(z)) + log|dx/dz| is the standard normal log density
    tr, prior = ProbitTransform(2.0, 7.0), Uniform(2.0, 7.0)
    z = np.linspace(-30.0, 30.0, 121)
    np.testing.assert_allclose(tr.inverse(z), 2.0 + 5.0 * stats.norm.cdf(z), rtol=1e-14)
    np.testing.assert_allclose(prior.logpdf(tr.inverse(z[np.abs(z) < 8])) +
                               tr.log_jacobian(z[np.abs(z) < 8]),
                               stats.norm.logpdf(z[np.abs(z) < 8]), rtol=1e-12)
    np.testing.assert_allclose(tr.log_jacobian(z), math.log(5.0) + stats.norm.logpdf(z),
                               rtol=1e-12)
    # a bound at 0 keeps full relative precision deep in the tail (a delay near 0)
    t0 = ProbitTransform(0.0, 0.01)
    zt = np.array([-30.0, -12.0, -6.0])
    np.testing.assert_allclose(t0.forward(t0.inverse(zt)), zt, rtol=1e-12)
    # near the upper bound the value is formed from it (1 - p never appears)
    x_hi = 0.01 - np.array([1e-12, 1e-9, 1e-6])
    np.testing.assert_allclose(t0.forward(x_hi), stats.norm.isf((0.01 - x_hi) / 0.01),
                               rtol=1e-12)
    assert t0.forward(np.array([0.0]))[0] == -np.inf and t0.forward(np.array([0.01]))[0] == np.inf
    assert np.all(np.isfinite(tr.log_jacobian(np.array([-700.0, 700.0]))))
    with pytest.raises(ParameterError, match="lower < upper"):
        ProbitTransform(1.0, 1.0)


def test_logit_jacobian_is_finite_far_out():
    tr = LogitTransform(0.0, 1.0)
    assert np.all(np.isfinite(tr.log_jacobian(np.array([-700.0, 700.0]))))


def _space() -> ParamSpace:
    return ParamSpace(
        (
            Param("a", Normal(0.0, 2.0), unit="V"),
            Param("w", HalfNormal(1.0), shape=(3,), unit="um/V"),
            Param("b", Uniform(-1.0, 2.0)),
            Param("c", LogNormal(0.0, 1.0)),
            Param("d", TruncatedNormal(1.0, 2.0, 0.0, 3.0), shape=(2,)),
        )
    )


@given(st.integers(0, 10_000))
@settings(max_examples=40, deadline=None)
def test_pack_unpack_round_trip(seed):
    space = _space()
    z = space.sample_prior(np.random.default_rng(seed), 1)[0]
    theta = space.unpack(z)
    assert set(theta) == set(space.names)
    assert np.shape(theta["w"]) == (3,) and isinstance(theta["a"], float)
    np.testing.assert_allclose(space.pack(theta), z, rtol=1e-9, atol=1e-9)


def test_batched_unpack_and_log_prior_match_single():
    space = _space().fix("b", 0.25)
    zs = space.sample_prior(np.random.default_rng(1), 6)
    batch = space.unpack(zs)
    assert batch["w"].shape == (6, 3) and batch["b"].shape == (6,)
    lp = space.log_prior(zs)
    for i in range(6):
        single = space.unpack(zs[i])
        np.testing.assert_allclose(batch["w"][i], single["w"])
        assert single["b"] == 0.25
        assert lp[i] == pytest.approx(space.log_prior(zs[i]))


def test_unpack_of_named_parameters_is_the_full_unpack_restricted_to_them():
    space = _space().fix("b", 0.25)
    zs = space.sample_prior(np.random.default_rng(2), 5)
    for z in (zs, zs[0]):
        full = space.unpack(z)
        some = space.unpack(z, names=["d", "b", "a"])
        assert set(some) == {"a", "b", "d"}
        for n in some:
            np.testing.assert_array_equal(some[n], full[n])
            assert type(some[n]) is type(full[n])
        assert space.unpack(z, names=[]) == {}
    with pytest.raises(KeyError, match="no parameter named 'x'"):
        space.unpack(zs, names=["a", "x"])


def test_log_prior_is_the_density_of_z():
    # oracle: the density of z = forward(x), x ~ prior, integrates to one and equals the
    # change-of-variables formula; check it by numerical integration in z for 1-D spaces
    for prior, _ in PRIORS:
        space = ParamSpace((Param("x", prior),))
        zs = np.linspace(-40, 40, 200_001)
        dens = np.exp(space.log_prior(zs[:, None]))
        assert np.trapezoid(dens, zs) == pytest.approx(1.0, abs=1e-4), prior


def test_log_prior_sampling_matches_prior_through_transform():
    # draws of z pushed through the inverse transform follow the prior (K–S)
    space = ParamSpace((Param("c", LogNormal(0.2, 0.4)),))
    z = space.sample_prior(np.random.default_rng(3), 3000)
    x = space.unpack(z)["c"]
    assert stats.kstest(x, space["c"].prior.cdf).pvalue > 1e-3


def test_log_prior_never_nan():
    space = _space()
    z = np.array([[1e308] * space.ndim, [-1e308] * space.ndim, [np.nan] * space.ndim])
    lp = space.log_prior(z)
    assert not np.any(np.isnan(lp))
    assert np.all(lp == -np.inf)


def test_fix_free_replace_and_names():
    space = _space()
    fixed = space.fix("w", [0.1, 0.2, 0.3])
    assert "w" not in fixed.names and "w" in fixed.all_names
    assert fixed.ndim == space.ndim - 3
    np.testing.assert_array_equal(fixed.unpack(np.zeros(fixed.ndim))["w"], [0.1, 0.2, 0.3])
    back = fixed.free("w")
    assert back.ndim == space.ndim and back.names[-1] == "w"
    wider = space.replace("a", prior=Normal(0.0, 10.0))
    assert wider["a"].prior == Normal(0.0, 10.0) and wider["a"].unit == "V"
    with pytest.raises(ParameterError, match="outside the prior support"):
        space.fix("c", -1.0)
    with pytest.raises(ParameterError, match="expected shape"):
        space.fix("w", [1.0, 2.0])
    with pytest.raises(ParameterError, match="cannot replace"):
        space.replace("a", shape=(2,))


def test_concat_namespaces_and_sub_theta():
    a = ParamSpace((Param("w", Normal(0, 1), shape=(2,)),))
    b = ParamSpace((Param("c", HalfNormal(1.0)),), fixed={"tau": 3.0},
                   fixed_params=(Param("tau", HalfNormal(1.0)),))
    joint = ParamSpace.concat({"static": a, "creep": b})
    assert joint.names == ("static.w", "creep.c")
    assert joint.all_names == ("static.w", "creep.c", "creep.tau")
    theta = joint.unpack(np.zeros(joint.ndim))
    assert ParamSpace.sub_theta(theta, "creep") == {"c": 1.0, "tau": 3.0}
    with pytest.raises(ParameterError, match="duplicate"):
        ParamSpace.concat([a, a])


def test_owners_name_the_parameter_of_each_coordinate():
    space = _space().fix("a", 0.5)
    # oracle: walk the slices one coordinate at a time
    expected = [next(n for n in space.names if space.slice_of(n).start <= i
                     < space.slice_of(n).stop) for i in range(space.ndim)]
    assert list(space.owners) == expected
    assert "a" not in space.owners and space.owners.count("w") == 3


def test_pack_rejects_unknown_and_missing_and_wrong_fixed():
    space = _space().fix("b", 0.5)
    theta = space.unpack(np.zeros(space.ndim))
    with pytest.raises(ParameterError, match="unknown"):
        space.pack({**theta, "zz": 1.0})
    with pytest.raises(ParameterError, match="missing"):
        space.pack({k: v for k, v in theta.items() if k != "a"})
    with pytest.raises(ParameterError, match="fixed at"):
        space.pack({**theta, "b": 0.7})


def test_pickle_round_trip_and_labels():
    space = _space().fix("b", 0.5)
    clone = pickle.loads(pickle.dumps(space))
    assert clone == space
    assert clone.labels[:4] == ["a", "w[0]", "w[1]", "w[2]"]
    assert "fixed = 0.5" in str(space)


def test_invalid_priors_raise():
    with pytest.raises(ParameterError):
        Uniform(1.0, 1.0)
    with pytest.raises(ParameterError):
        Normal(0.0, -1.0)
    with pytest.raises(ParameterError):
        HalfNormal(float("nan"))
    with pytest.raises(ParameterError, match="no mass"):
        TruncatedNormal(0.0, 1.0, 60.0, 61.0)
