"""Atomic writes: whole or nothing, and the permissions a plain open() would give; a
failed run takes back what it created and nothing else."""

from __future__ import annotations

import json
import stat

import numpy as np
import pytest

from bayeshyst.files import atomic_path, atomic_paths, removed_on_failure
from bayeshyst.outputs.files import jsonable, nonfinite_fields, write_json


def _mode(path):
    return stat.S_IMODE(path.stat().st_mode)


def test_new_files_get_the_mode_of_a_plain_open(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")  # the oracle: what open() gives under this umask
    with atomic_path(tmp_path / "new.txt") as tmp:
        tmp.write_text("y")
    assert _mode(tmp_path / "new.txt") == _mode(plain)
    write_json(tmp_path / "s.json", {"a": float("nan")})
    assert _mode(tmp_path / "s.json") == _mode(plain)
    assert json.loads((tmp_path / "s.json").read_text()) == {"a": None}


def test_nonfinite_fields_are_where_json_gets_null():
    obj = {"a": 1.0, "params": {"w[0]": {"sd": float("inf"), "mean": 0.5}},
           "rows": [1, float("nan"), {"x": np.float32("-inf")}], "arr": np.array([1.0, np.inf]),
           "ok": True, "n": 3, "text": "nan"}
    assert nonfinite_fields(obj) == ["params.w[0].sd", "rows[1]", "rows[2].x", "arr[1]"]
    plain = jsonable(obj)
    assert plain["params"]["w[0]"]["sd"] is None and plain["rows"][1] is None
    assert plain["rows"][2]["x"] is None and plain["arr"] == [1.0, None]
    assert nonfinite_fields(plain) == [] and plain["text"] == "nan"


def test_replacing_keeps_the_old_mode(tmp_path):
    target = tmp_path / "t.txt"
    target.write_text("old")
    target.chmod(0o640)
    with atomic_path(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and _mode(target) == 0o640


def test_failure_leaves_targets_untouched_and_no_temp_files(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("A")

    class Boom(Exception):
        pass

    with pytest.raises(Boom), atomic_paths([a, b]) as (ta, tb):
        ta.write_text("new A")
        tb.write_text("new B")
        raise Boom
    assert a.read_text() == "A" and not b.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


# ------------------------------------------------------------------- removed_on_failure
class Failed(Exception):
    pass


def _listing(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_a_failed_run_removes_its_folder_and_the_parents_it_created(tmp_path):
    out = tmp_path / "a" / "b" / "out"
    with pytest.raises(Failed), removed_on_failure(out):
        (out / "checkpoints").mkdir(parents=True)
        (out / "checkpoints" / "fit.h5").write_bytes(b"chains")
        (out / "posterior.nc").write_bytes(b"half")
        raise Failed
    assert list(tmp_path.iterdir()) == []  # not even tmp_path/a


def test_a_failed_run_keeps_what_was_there_before(tmp_path):
    out = tmp_path / "out"
    (out / "old").mkdir(parents=True)
    (out / "notes.txt").write_text("mine")
    (out / "checkpoint.h5").write_bytes(b"earlier run")
    (out / "old" / "summary.json").write_text("{}")
    with pytest.raises(Failed), removed_on_failure(out):
        # a resumed run appends to the earlier checkpoint and adds files of its own
        with (out / "checkpoint.h5").open("ab") as fh:
            fh.write(b" + more")
        (out / "old" / "new.png").write_bytes(b"png")
        (out / "new" / "deep").mkdir(parents=True)
        (out / "new" / "deep" / "x").write_text("x")
        raise Failed
    assert _listing(out) == ["checkpoint.h5", "notes.txt", "old", "old/summary.json"]
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "checkpoint.h5").read_bytes() == b"earlier run + more"


def test_nothing_is_removed_after_the_first_result(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(Failed), removed_on_failure(out) as outputs:
        out.mkdir()
        (out / "checkpoint.h5").write_bytes(b"chains")
        outputs.keep()
        (out / "posterior.nc").write_bytes(b"x")
        raise Failed
    assert _listing(out) == ["checkpoint.h5", "posterior.nc"]


def test_a_created_file_matching_results_is_a_result(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(Failed), removed_on_failure(out, results=("fits/*.json",)):
        (out / "fits").mkdir(parents=True)
        (out / "work").mkdir()
        (out / "work" / "a.h5").write_bytes(b"x")
        raise Failed
    assert not out.exists()  # a folder named fits/ is not a result, a stored fit is
    with pytest.raises(Failed), removed_on_failure(out, results=("fits/*.json",)):
        (out / "fits").mkdir(parents=True)
        (out / "fits" / "0a1b.json").write_text("{}")
        (out / "work").mkdir()
        raise Failed
    assert _listing(out) == ["fits", "fits/0a1b.json", "work"]


def test_success_and_interrupt_remove_nothing(tmp_path):
    out = tmp_path / "out"
    with removed_on_failure(out):
        out.mkdir()
        (out / "summary.json").write_text("{}")
    assert _listing(out) == ["summary.json"]
    # an interrupted run is resumed, not failed: its checkpoint stays
    with pytest.raises(KeyboardInterrupt), removed_on_failure(tmp_path / "int"):
        (tmp_path / "int").mkdir()
        (tmp_path / "int" / "checkpoint.h5").write_bytes(b"x")
        raise KeyboardInterrupt
    assert (tmp_path / "int" / "checkpoint.h5").exists()


def test_links_are_removed_not_followed(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "precious.txt").write_text("keep")
    out = tmp_path / "out"
    out.mkdir()
    (out / "old_link").symlink_to(outside)
    with pytest.raises(Failed), removed_on_failure(out):
        (out / "new_link").symlink_to(outside)
        raise Failed
    assert _listing(out) == ["old_link"]
    assert (outside / "precious.txt").read_text() == "keep"


def test_an_output_path_that_is_a_file_is_left_alone(tmp_path):
    out = tmp_path / "out"
    out.write_text("a file, not a folder")
    with pytest.raises(Failed), removed_on_failure(out):
        raise Failed
    assert out.read_text() == "a file, not a folder"
