"""Atomic writes: whole or nothing, and the permissions a plain open() would give."""

from __future__ import annotations

import json
import stat

import pytest

from bayeshyst.files import atomic_path, atomic_paths
from bayeshyst.report.files import write_json


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
