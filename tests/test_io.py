"""Atomic writes (``bezmotion._src.io``): ordinary file permissions, no half-written files; output folders checked before work."""

from __future__ import annotations

import os
import stat

import pytest

from bezmotion._src.io import _umask, atomic_path, atomic_write_bytes, atomic_write_text, check_writable_folder


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_umask_is_read_without_changing_it():
    old = os.umask(0o027)
    try:
        assert _umask() == 0o027
        assert _umask() == 0o027
    finally:
        os.umask(old)


def test_atomic_writes_give_new_files_ordinary_permissions(tmp_path, umask_022):
    atomic_write_text(tmp_path / "a.txt", "text\n")
    atomic_write_bytes(tmp_path / "b.bin", b"\x00\x01")
    with atomic_path(tmp_path / "c.npz", suffix=".npz") as tmp:
        tmp.write_bytes(b"x")
    for name in ("a.txt", "b.bin", "c.npz"):
        assert _mode(tmp_path / name) == 0o644, name  # 0o666 & ~0o022, as open() would give
        # not the temporary file's 0o600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.bin", "c.npz"]


def test_atomic_write_keeps_the_mode_of_the_file_it_replaces(tmp_path, umask_022):
    path = tmp_path / "script.sh"
    path.write_text("old\n")
    os.chmod(path, 0o750)
    atomic_write_text(path, "new\n")
    assert path.read_text() == "new\n" and _mode(path) == 0o750


def test_a_failed_atomic_write_leaves_the_old_file(tmp_path):
    path = tmp_path / "a.txt"
    path.write_text("old\n")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert path.read_text() == "old\n" and [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_a_writable_folder_is_one_whose_nearest_existing_ancestor_is_a_folder(tmp_path):
    check_writable_folder(tmp_path)
    check_writable_folder(tmp_path / "not" / "yet" / "made")  # made when written
    (tmp_path / "file").write_text("")
    for under_a_file in (tmp_path / "file", tmp_path / "file" / "sub" / "dir"):
        with pytest.raises(ValueError, match=f"^{tmp_path}/file is a file, not a folder$"):
            check_writable_folder(under_a_file)
    assert not (tmp_path / "not").exists()  # checking makes nothing


def test_atomic_temporaries_carry_the_process_id(tmp_path):
    with atomic_path(tmp_path / "a.txt") as tmp:
        assert tmp.name.startswith(f".a.txt.{os.getpid()}.") and tmp.name.endswith(".tmp")
        tmp.write_text("x")
