"""Work shared with forked children (bayeshyst.workers.run_forked) and the figures saved so.

Oracles: every item's side effect happens exactly once whatever the number of
processes; the PNG files are byte for byte those of a one-process run; a failure in a
child is raised in the caller as the same exception type, after every share finished.
"""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path

import numpy as np
import pytest

from bayeshyst.outputs.files import write_figures
from bayeshyst.workers import WorkerTraceback, run_forked

needs_fork = pytest.mark.skipif("fork" not in mp.get_all_start_methods(),
                                reason="no fork on this platform: run_forked runs in-process")


def _touch(folder: Path):
    def fn(item: int) -> None:
        path = folder / f"{item}.txt"
        # a second call for an item would find its file: count calls in the content
        old = path.read_text() if path.exists() else ""
        path.write_text(old + "x")
    return fn


@pytest.mark.parametrize("n_jobs", [1, 2, 3])
def test_every_item_runs_exactly_once(tmp_path, n_jobs):
    run_forked(_touch(tmp_path), list(range(7)), n_jobs)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"{i}.txt" for i in range(7))
    assert all(p.read_text() == "x" for p in tmp_path.iterdir())


@needs_fork
def test_a_failure_in_a_child_is_raised_here_after_every_share(tmp_path):
    touch = _touch(tmp_path)

    def fn(item: int) -> None:
        if item in (1, 3):  # items of the child (n = 2: the child takes 1, 3, 5)
            raise ValueError(f"item {item} refused")
        touch(item)

    with pytest.raises(ValueError, match="item 1 refused") as info:
        run_forked(fn, list(range(6)), 2)
    assert isinstance(info.value.__cause__, WorkerTraceback)
    # the other items ran, in both processes
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0.txt", "2.txt", "4.txt", "5.txt"]


@needs_fork
def test_a_failure_here_comes_first_when_its_item_does(tmp_path):
    def fn(item: int) -> None:
        raise KeyError(item)

    with pytest.raises(KeyError) as info:
        run_forked(fn, [0, 1, 2], 2)
    assert info.value.args == (0,)


def _figures():
    from matplotlib.figure import Figure

    out = {}
    for i in range(5):
        fig = Figure(figsize=(3, 2), dpi=80)
        ax = fig.subplots()
        x = np.linspace(0.0, 1.0, 50)
        ax.plot(x, np.sin((i + 1) * np.pi * x))
        ax.set_title(f"figure {i}")
        out[f"sub/f{i}.png" if i % 2 else f"f{i}.png"] = fig
    return out


def test_figures_saved_over_two_processes_are_the_one_process_files(tmp_path):
    figs = _figures()
    one, two = tmp_path / "one", tmp_path / "two"
    assert write_figures(one, figs, n_jobs=1) == list(figs)
    assert write_figures(two, figs, n_jobs=2) == list(figs)
    for name in figs:
        assert (two / name).read_bytes() == (one / name).read_bytes(), name
    assert sorted(str(p.relative_to(two)) for p in two.rglob("*.png")) == sorted(figs)
