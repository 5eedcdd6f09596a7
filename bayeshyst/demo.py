"""What ``bayeshyst demo`` runs: the bundled virtual-actuator data and the demo's plans.

A plan is the report (:func:`~bayeshyst.workflow.run_report`) at a budget sized for a
2-core laptop: which models, which of the bundled frequencies, and the
:class:`~bayeshyst.workflow.ReportSettings` of every stage.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bayeshyst.errors import DataError
from bayeshyst.inference.settings import SamplerSettings
from bayeshyst.workflow import ReportSettings

__all__ = ["DEMO_DEFAULT", "DEMO_QUICK", "DemoPlan", "bundled_data"]


@dataclass(frozen=True)
class DemoPlan:
    """What ``bayeshyst demo`` runs: models and budgets sized for a 2-core laptop."""

    models: tuple[str, ...]
    settings: ReportSettings
    description: str
    frequencies_hz: tuple[float, ...] | None = None  # None: every frequency of the data


#: ``bayeshyst demo --quick``: a PI model with and without second-order dynamics (both
#: with an exactly drawn linear block, so every fit converges in seconds), the lowest and
#: highest of the five frequencies, no leave-one-frequency-out, one diagnosis round.
#: Every section in about half a minute on 2 cores (measured in benchmarks/RESULTS.md);
#: Bouc–Wen and the GP are in the default demo.
DEMO_QUICK = DemoPlan(
    models=("pi_play(n_operators=5)", "pi_play(n_operators=5)+second_order"),
    settings=ReportSettings(sampler=SamplerSettings(max_steps=5000),
                            lofo=False, max_refits=0, max_rounds=1, max_candidates=1,
                            design_draws=8),
    description="quick: PI with and without second-order dynamics, 1/200 Hz, no LOFO, "
                "one diagnosis round",
    frequencies_hz=(1.0, 200.0))

#: ``bayeshyst demo``: the classic families and the GP peer on all five frequencies, with
#: the leave-one-frequency-out fits and three diagnosis rounds of two candidates each (the
#: bundled actuator hides asymmetry, dynamics, creep, drift and a delay: round 1 keeps the
#: asymmetry, round 2 the delay and creep as a pair, round 3 the branch-shape correction).
#: A fourth round finds the dynamics too, but its fit (second-order on top of the shape
#: correction, 60 coordinates) did not converge in 5 000 steps and took 28 minutes on 2
#: loaded cores; ``bayeshyst report`` runs up to six rounds. Every fit of the three rounds
#: converges at the default sampler budget (times in benchmarks/RESULTS.md).
DEMO_DEFAULT = DemoPlan(
    models=("pi_play(n_operators=8)", "bouc_wen", "gp_memory"),
    settings=ReportSettings(sampler=SamplerSettings(max_steps=5000),
                            lofo=True, max_refits=1, max_rounds=3, max_candidates=2,
                            design_draws=16),
    description="3 models, 5 frequencies, leave-one-frequency-out, three diagnosis rounds, "
                "up to 5000 steps per ensemble")


def bundled_data(name: str = "virtual_multifreq.csv", *,
                 fallback_dir: str | Path | None = None) -> Path:
    """Path of a bundled virtual-actuator dataset.

    The datasets ship in the repository's ``data/`` folder; an installation without it
    (a wheel) regenerates them, bit for bit, with :func:`bayeshyst.data.virtual.bundle`
    into ``fallback_dir``.

    Raises
    ------
    DataError
        If the dataset is neither shipped nor can be regenerated (no ``fallback_dir``).
    """
    shipped = Path(__file__).resolve().parents[1] / "data" / name
    if shipped.is_file():
        return shipped
    if fallback_dir is None:
        raise DataError(f"bundled dataset {name} not found at {shipped} and no folder to "
                        "regenerate it into")
    from bayeshyst.data.virtual import bundle

    made = {p.name: p for p in bundle(fallback_dir)}
    if name not in made:
        raise DataError(f"no bundled dataset named {name}; have {sorted(made)}")
    return made[name]
