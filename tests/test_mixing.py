"""Why a run did not converge (bayeshyst.inference.mixing), on chains with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bayeshyst.inference.mixing import COLLINEAR, explain_nonconvergence, separate_regions
from bayeshyst.params import Normal, Param, ParamSpace

SPACE = ParamSpace((Param("a", Normal(0.0, 1.0), unit="V"), Param("b", Normal(0.0, 1.0)),
                    Param("c", Normal(0.0, 1.0), shape=(1,))))


def _ar1(rng, phi, shape):
    """AR(1) series along axis 1 with unit marginal sd: tau = (1 + phi) / (1 - phi)."""
    x = np.empty(shape)
    x[:, 0] = rng.standard_normal(shape[:1] + shape[2:])
    e = rng.standard_normal(shape) * math.sqrt(1 - phi**2)
    for s in range(1, shape[1]):
        x[:, s] = phi * x[:, s - 1] + e[:, s]
    return x


def _log_normal_density(x):
    return -0.5 * np.sum(x**2, axis=-1) - 0.5 * x.shape[-1] * math.log(2 * math.pi)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_independent_well_mixed_ensembles_give_nothing_to_say(seed):
    rng = np.random.default_rng(seed)
    chains = rng.standard_normal((2, 400, 16, 3))
    assert explain_nonconvergence(chains, _log_normal_density(chains), SPACE,
                                  tau_factor=50) == ()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pair_the_data_cannot_separate_is_named_and_only_it(seed):
    rng = np.random.default_rng(seed)
    chains = rng.standard_normal((2, 400, 16, 3))
    # b follows a (correlation 1 / sqrt(1 + 0.05^2) = 0.9988); c correlated at 0.9 only
    chains[..., 1] = chains[..., 0] + 0.05 * rng.standard_normal(chains.shape[:3])
    chains[..., 2] = 0.9 * chains[..., 0] + math.sqrt(1 - 0.81) * chains[..., 2]
    said = explain_nonconvergence(chains, _log_normal_density(chains), SPACE, tau_factor=50)
    pairs = [s for s in said if f"correlation of {COLLINEAR:g}" in s]
    assert len(pairs) == 1 and "a ~ b (+0.99" in pairs[0] and "c[0]" not in pairs[0]


def test_slow_coordinates_are_named_with_the_steps_they_need():
    rng = np.random.default_rng(3)
    chains = rng.standard_normal((2, 2000, 16, 3))
    chains[..., 2] = _ar1(rng, 0.98, (2, 2000, 16))  # tau = 99: 50 tau > 2 000 steps
    said = explain_nonconvergence(chains, _log_normal_density(chains), SPACE, tau_factor=50)
    slow = [s for s in said if s.startswith("slowest to mix")]
    assert len(slow) == 1 and "c[0]" in slow[0] and "a (" not in slow[0]
    need = int(slow[0].split("would be at least ")[1].split(" ")[0])
    # a lower bound, as it says (a chain of 20 tau underestimates tau), but not a loose one
    assert 0.5 * 50 * 99 < need < 1.1 * 50 * 99


@pytest.mark.parametrize("w_a", [0.5, 0.8, 0.97])
def test_separate_regions_get_the_weights_of_the_mixture_they_sample(w_a):
    # ensemble 0 samples N(0, I) and ensemble 1 N(m, 0.5^2 I) of the mixture
    # w_a N(0, I) + (1 - w_a) N(m, 0.25 I), far apart: each region's mass is its weight
    rng = np.random.default_rng(4)
    d, m = 3, np.array([12.0, 0.0, 0.0])
    x0 = rng.standard_normal((1, 500, 16, d))
    x1 = m + 0.5 * rng.standard_normal((1, 500, 16, d))
    lp0 = math.log(w_a) + _log_normal_density(x0)
    lp1 = (math.log(1 - w_a) + _log_normal_density((x1 - m) / 0.5) - d * math.log(0.5))
    found = separate_regions(np.concatenate([x0, x1]), np.concatenate([lp0, lp1]))
    assert found is not None
    regions, coord, sep = found
    assert coord == 0 and sep > 10
    assert regions[0].weight == pytest.approx(w_a, abs=0.03)
    said = explain_nonconvergence(np.concatenate([x0, x1]), np.concatenate([lp0, lp1]), SPACE,
                                  tau_factor=50)
    assert said[0].startswith("the 2 ensembles sit in separate regions (a: ")
    assert " V; " in said[0]  # the separating coordinate in its unit


def test_ensembles_a_few_sd_apart_that_overlap_are_not_separate_regions():
    # slow mixing, not multimodality: the means differ by 2 sd, the ranges overlap
    rng = np.random.default_rng(5)
    chains = rng.standard_normal((2, 400, 16, 3))
    chains[1, ..., 0] += 2.0
    assert separate_regions(chains, _log_normal_density(chains)) is None
