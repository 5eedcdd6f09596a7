"""Gaussian-process hysteresis model: Tao, Li and Zhu [64] and a memory-feature extension.

``GPHysteresis`` is a scikit-learn regressor from the input voltage of a record to its
displacement, simulated in *free run* (no measured output is used in prediction):

* ``features="rate"`` -- Tao, Li, Zhu, Sensors and Actuators A 295 (2019) [64]: a GP from
  ``(u, du/dt)`` to ``y``. Captures a periodic major loop and its rate dependence, but
  the same ``(u, du/dt)`` occurs on different branches of nested minor loops, which it
  therefore averages.
* ``features="memory"`` -- adds the Preisach memory: branch direction and the input and
  output at the last two input reversals that survive the wiping-out property
  (:func:`bayeshyst.gp.features.memory_indices` gives the exact stack rule). The GP
  regresses the increment along the current branch, ``y - y_r1``: for a Preisach
  operator it depends only on the inputs (Mayergoyz' representation), and it
  generalised far better than the absolute output when this was decided (trained on
  random reversals, tested on a decaying sine: 0.23 % vs 1.1 % NRMSE).
* ``features="static"`` -- the memory features without the rate: a rate-independent
  baseline.

Training is series-parallel (teacher forcing): the output features at the reversals
are the *measured* outputs. Prediction is parallel (free run): they are the model's own
predictive means, computed reversal by reversal (the reversal structure depends on the
input only), after which every sample is predicted in one vectorised pass -- O(number
of reversals) sequential steps, not O(N). The predictive standard deviation is the
GP's latent one at the features so formed: the uncertainty of the fed-back outputs is
not propagated (plug-in). After :meth:`GPHysteresis.sample_hyperparameters` every
draw runs its own free run, so the spread between the draws' fed-back outputs does
enter the mixture.

Inputs and targets are standardised with the mean and standard deviation of all
candidate samples (see :meth:`GPHysteresis.fit_records`); ``n_train`` of them form the
GP's training set, chosen by ``subset``:

* ``"farthest"`` (default) -- greedy farthest-point sampling in the standardised
  feature space (even coverage of feature space, including its sparse corners);
* ``"stratified"`` -- one sample drawn at random from each of ``n_train`` consecutive,
  equally long time strata (every cycle and record represented by its length).

``benchmarks/bench_gp.py`` measures error and time against the subset size for both
(10^5-sample records, RESULTS.md): equal accuracy for ``n_train >= 1000`` (memory
variant, held-out NRMSE 0.063-0.084 %), but the stratified draw occasionally misses a
region of feature space that the free run then extrapolates into (2.4 % at
``n_train=500``; over 5 seeds at 500: one such failure, others 0.086-0.099 %, while
farthest-point gave 0.093-0.108 % every time), hence the default.
The kernel is ``ConstantKernel * ARD-RBF (or Matern 5/2) + WhiteKernel``; its log
hyperparameters maximise the marginal likelihood by L-BFGS-B with an analytic
``O(m^2 d)`` gradient (equal to sklearn's, which forms an (m, m, d) tensor and is
several times slower), from the initial values and ``n_restarts_optimizer`` random
starts.

The marginal likelihood is that of the series-parallel regression: it scores the GP
with the *measured* outputs at the reversals and never sees the free run, in which the
model's own outputs are fed back. Its highest optimum can therefore be an unstable
recurrence. Measured on the bundled ``data/virtual_multifreq.csv`` (four cycles of one
sine per record, the reversal outputs creeping by about 0.1 um per cycle), 20 random
states per frequency: at 1 Hz 11 and at 200 Hz 5 of them ended at an optimum with a
length-scale of 0.29-0.42 um on a reversal-output feature (``y_r1`` or ``y_r2``), none
at 10, 50 and 100 Hz. Such an optimum tells the few training branches apart by their
measured reversal outputs (log marginal likelihood 3925-3966 at 1 Hz against 3781-3934
at the sound optima; 3970 against 3917-3958 at 200 Hz), but in the free run the
predicted reversal outputs drift past the trained ones by more than a length-scale,
the GP reverts to its prior mean and the loop collapses (free-run NRMSE 25-50 %
against 0.09-0.22 %), while the fit reported convergence. Hence the optima of all
starts are tried from the highest marginal likelihood down and the first whose free
run reproduces the training records is kept: free-run RMSE over the training
candidates at most :data:`FREE_RUN_TOLERANCE` times the teacher-forced (one-step)
RMSE over the same samples (``free_run_ratio_``, measured 0.9-3.9 at the sound optima
and 310-610 at the collapsing ones). With it every one of the 100 fits above reached
0.09-0.17 %, and no sound optimum was rejected. When no optimum passes, the fit warns
and sets ``converged_`` False. The check costs one mean-only free run of the training
records per optimum tried (0.01-0.02 s for one 801-sample record, 0.25 s for five
records and 1000 training points; a fit takes 5-12 s).

Fits to several frequencies at once show a milder, graded loss that the check lets
pass: ratio 4.4-15, training NRMSE 0.5-2.7 % depending on the random state (the
subset and the restarts), with a shorter ``y_r1`` length-scale (4.2-6.3 um against
9.7-44 um) at the worse ones. The records' reversal outputs differ by about 1 um between
frequencies, so the likely cause is the static variant's pitfall (class Notes): the
GP reads the rate from the measured reversal outputs.

Where each variant wins, and its pitfalls
-----------------------------------------
Where each variant wins (``tests/test_gp.py``, ``benchmarks/bench_gp.py``): on one
periodic excitation both are below the noise level (1 Hz sine: rate 0.024 %,
memory 0.040 % NRMSE against the truth), the rate variant with two features and
no sequential free run; with nested minor loops re-entered from different
histories the memory variant wins (1.05 % vs 3.26 %), on held-out frequencies
(0.04 % vs 0.12-0.70 %: in the rate variant ``du/dt`` must also encode the branch,
which breaks down across a wide band of rates) and on 10^5-sample multi-frequency
minor-loop records (0.06-0.08 % vs 1.4-1.5 % at ``n_train >= 1000``).

Pitfalls of the output features (series-parallel training): a memory GP
extrapolates poorly to reversal levels it has not seen (trained on one periodic
loop, it knows two), errors at reversals propagate along the chain of branches
(measured: growing from 0.02 to 1.8 um over the nested loops of a decaying sine
when the training had few small loops), and the ``"static"`` variant trained on
several frequencies learns to read the rate from the measured reversal outputs,
which fails in free run (11 % NRMSE on its own training records); identify it at
one frequency. When the optimum makes use of the second-reversal features, held-out
(r1, r2) combinations the subset never saw are extrapolated badly (the 2.4 % in
RESULTS.md); farthest-point subsets cover that space and avoided it.

The package
-----------
* :mod:`bayeshyst.gp.model` -- :class:`GPHysteresis` (fit, hyperparameter sampling),
  :func:`fit_gp_inverse`;
* :mod:`bayeshyst.gp.prediction` -- its free run and per-cycle log densities (the
  :class:`~bayeshyst.inference.protocols.Predictor` protocol);
* :mod:`bayeshyst.gp.hyperparameters` -- the log-hyperparameter posterior as a
  :class:`~bayeshyst.inference.protocols.SamplingTarget` of the shared sampler;
* :mod:`bayeshyst.gp.kernel` -- kernel, marginal likelihood, conditioned GP;
* :mod:`bayeshyst.gp.features` -- rate and memory features, training subsets;
* :func:`gp_from_spec` -- the model specs ``"gp"`` and ``"gp_memory"`` of a comparison.

The names below load on first use (PEP 562): ``gp_from_spec`` answers whether a spec
is a GP without importing scikit-learn.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bayeshyst.gp.model import GPHysteresis

__all__ = [
    "BOUNDS",
    "FREE_RUN_TOLERANCE",
    "GPHysteresis",
    "GPPrediction",
    "HyperparameterReport",
    "HyperparameterTarget",
    "UnitLogDensity",
    "fit_gp_inverse",
    "gp_features",
    "gp_from_spec",
    "gp_names",
    "records_to_X",
]

_LAZY = {
    "BOUNDS": ("bayeshyst.gp.kernel", "BOUNDS"),
    "FREE_RUN_TOLERANCE": ("bayeshyst.gp.model", "FREE_RUN_TOLERANCE"),
    "GPHysteresis": ("bayeshyst.gp.model", "GPHysteresis"),
    "GPPrediction": ("bayeshyst.inference.protocols", "Prediction"),
    "HyperparameterReport": ("bayeshyst.gp.hyperparameters", "HyperparameterReport"),
    "HyperparameterTarget": ("bayeshyst.gp.hyperparameters", "HyperparameterTarget"),
    "UnitLogDensity": ("bayeshyst.inference.protocols", "UnitLogDensity"),
    "fit_gp_inverse": ("bayeshyst.gp.model", "fit_gp_inverse"),
    "records_to_X": ("bayeshyst.gp.features", "records_to_X"),
}

#: Model specs that build a GP, and their features: ``gp`` is the (u, du/dt) form of
#: ref. [64], ``gp_memory`` adds the reversal-memory features.
_SPECS = {"gp": "rate", "gp_memory": "memory"}


def gp_names() -> list[str]:
    """The model specs that build a GP (``gp``, ``gp_memory``), sorted."""
    return sorted(_SPECS)


def gp_features(spec: str) -> str | None:
    """The features of the GP a spec names (``"rate"``, ``"memory"``), None if not a GP."""
    return _SPECS.get(spec.strip()) if isinstance(spec, str) else None


def gp_from_spec(spec: str, *, n_train: int = 1000,
                 random_state: int | None = None) -> GPHysteresis | None:
    """The unfitted GP a model spec names, or None when the spec is not a GP.

    The one place that decides which specs are GPs: ``"gp"`` (features ``"rate"``)
    and ``"gp_memory"`` (features ``"memory"``). Callers ask the object it returns
    what it can do, not its name.

    Parameters
    ----------
    spec : str
        A model spec (surrounding blanks ignored).
    n_train : int, default 1000
        Training-subset size.
    random_state : int, optional
        Subset draws and optimiser restarts.

    Returns
    -------
    GPHysteresis or None
    """
    features = gp_features(spec)
    if features is None:
        return None
    from bayeshyst.gp.model import GPHysteresis

    return GPHysteresis(features=features, n_train=n_train, random_state=random_state)


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module 'bayeshyst.gp' has no attribute {name!r}")
    module, attr = _LAZY[name]
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
