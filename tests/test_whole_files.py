"""Files written whole or not at all (io/whole_files.py): what an interrupted write leaves."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from motionbase.io.whole_files import folder_problem, whole_file, whole_folder


def _left(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_a_file_is_replaced_at_the_end_and_an_interrupted_write_changes_nothing(tmp_path):
    target = tmp_path / "washout.toml"
    target.write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with whole_file(target) as part:
            part.write_text("half of the new")
            raise KeyboardInterrupt  # Ctrl-C while it writes
    assert target.read_text() == "old" and _left(tmp_path) == ["washout.toml"]
    with whole_file(target) as part:
        assert part.parent == tmp_path and part != target
        part.write_text("new")
        assert target.read_text() == "old"  # not until the block ends
    assert target.read_text() == "new" and _left(tmp_path) == ["washout.toml"]


def test_a_symbolic_link_keeps_pointing_at_the_file_it_names(tmp_path):
    (tmp_path / "real").mkdir()
    real = tmp_path / "real" / "w.toml"
    real.write_text("old")
    link = tmp_path / "link.toml"
    link.symlink_to(real)
    with whole_file(link) as part:
        part.write_text("new")
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert real.read_text() == "new"


def test_a_new_folder_appears_with_all_its_files_or_not_at_all(tmp_path):
    out = tmp_path / "omct"
    with pytest.raises(RuntimeError):
        with whole_folder(out) as staging:
            (staging / "omct.json").write_text("{}")
            raise RuntimeError("the plotting failed")
    assert _left(tmp_path) == []  # no folder, no staging folder
    with whole_folder(out) as staging:
        for name in ("omct.json", "table.md", "bode_roll.png"):
            (staging / name).write_text(name)
        assert not out.exists()
    assert _left(out) == ["bode_roll.png", "omct.json", "table.md"]
    assert _left(tmp_path) == ["omct"]


def test_into_a_folder_that_is_there_the_old_files_stay_until_the_end(tmp_path):
    out = tmp_path / "omct"
    out.mkdir()
    (out / "omct.json").write_text("old")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(KeyboardInterrupt):
        with whole_folder(out) as staging:
            (staging / "omct.json").write_text("new")
            raise KeyboardInterrupt
    assert _left(out) == ["notes.txt", "omct.json"] and (out / "omct.json").read_text() == "old"
    with whole_folder(out) as staging:
        (staging / "omct.json").write_text("new")
        (staging / "table.md").write_text("table")
    assert _left(out) == ["notes.txt", "omct.json", "table.md"]
    assert (out / "omct.json").read_text() == "new" and (out / "notes.txt").read_text() == "mine"


def test_folder_problem_names_the_part_of_the_path_in_the_way(tmp_path):
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    assert folder_problem(tmp_path / "new" / "deeper") == ""
    assert folder_problem(blocker / "x" / "y") == f"{blocker} is not a folder"
    assert not (tmp_path / "new").exists()  # nothing created
