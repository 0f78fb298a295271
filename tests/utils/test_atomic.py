"""The one atomic writer: a failed write leaves the old file whole and no temp file behind."""

import json

import pytest

from drem_maniskill.utils.atomic import atomic_path, copy_file, promote, write_json, write_text


def test_failed_write_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    target = write_text(tmp_path / "a.txt", "old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed mid-write")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_json_and_copy_replace_whole_files(tmp_path):
    write_json(tmp_path / "d.json", {"a": 1})
    write_json(tmp_path / "d.json", {"b": 2})
    assert json.loads((tmp_path / "d.json").read_text()) == {"b": 2}
    copy_file(tmp_path / "d.json", tmp_path / "sub" / "e.json")
    assert (tmp_path / "sub" / "e.json").read_text() == (tmp_path / "d.json").read_text()
    assert oct((tmp_path / "sub" / "e.json").stat().st_mode & 0o777) == oct(0o644)


def test_a_folder_replaces_a_non_empty_folder(tmp_path):
    old = tmp_path / "ckpt"
    old.mkdir()
    (old / "stale.bin").write_text("x")
    with atomic_path(old, directory=True) as tmp:
        (tmp / "model.zip").write_text("new")
    assert sorted(p.name for p in old.iterdir()) == ["model.zip"]
    assert [p.name for p in tmp_path.iterdir()] == ["ckpt"]


def test_promote_renames_a_finished_partial_file(tmp_path):
    partial = write_text(tmp_path / "tree.h5.partial", "nodes")
    promote(partial, tmp_path / "tree.h5")
    assert not partial.exists() and (tmp_path / "tree.h5").read_text() == "nodes"
