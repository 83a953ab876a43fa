"""Atomic writes without replacing a file that appeared meanwhile, and their errors."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pandas as pd
import pytest

import graphcal.core.atomic as atomic
from graphcal.core.atomic import (
    atomic_write_table,
    atomic_write_text,
    clear_protected,
    is_protected,
    protect,
    publish,
    rename_no_replace,
)
from graphcal.core.errors import OutputExistsError, os_error_message


@pytest.fixture(autouse=True)
def _no_protections():
    clear_protected()
    yield
    clear_protected()


def _appear_while_writing(monkeypatch, path: Path) -> None:
    fsync = os.fsync

    def racing(fd: int) -> None:
        fsync(fd)
        if not path.exists():
            path.write_text("theirs")

    monkeypatch.setattr(os, "fsync", racing)


def test_no_replace_keeps_a_file_that_appeared_meanwhile(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "out.json"
    _appear_while_writing(monkeypatch, path)
    with pytest.raises(OutputExistsError, match="written by another process meanwhile"):
        atomic_write_text(path, "ours", replace=False)
    assert path.read_text() == "theirs"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_replace_replaces_it(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "out.json"
    _appear_while_writing(monkeypatch, path)
    atomic_write_text(path, "ours", replace=True)
    assert path.read_text() == "ours"


def test_no_replace_writes_a_new_file(tmp_path: Path) -> None:
    path = tmp_path / "out.csv"
    atomic_write_table(pd.DataFrame({"a": [1, 2]}), path, replace=False)
    assert path.read_text() == "a\n1\n2\n"
    assert oct(path.stat().st_mode & 0o777) == oct(0o644)
    assert path.stat().st_nlink == 1  # the temporary's link is gone
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_a_table_is_not_replaced_either(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "out.csv"
    _appear_while_writing(monkeypatch, path)
    with pytest.raises(OutputExistsError):
        atomic_write_table(pd.DataFrame({"a": [1]}), path, replace=False)
    assert path.read_text() == "theirs"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_a_protected_path_is_not_replaced_by_default(tmp_path: Path, monkeypatch) -> None:
    """What the command line does for an output it checked without --overwrite: writers
    of any module publish it without replacing."""
    path = tmp_path / "report.html"
    protect(path)
    assert is_protected(tmp_path / "." / "report.html")
    _appear_while_writing(monkeypatch, path)
    with pytest.raises(OutputExistsError):
        atomic_write_text(path, "ours")
    assert path.read_text() == "theirs"


def test_protection_ends_once_written(tmp_path: Path) -> None:
    path = tmp_path / "report.html"
    protect(path)
    atomic_write_text(path, "first")
    assert not is_protected(path)
    atomic_write_text(path, "second")  # the default replaces again
    assert path.read_text() == "second"


@pytest.mark.parametrize("renameat2", [True, False])
def test_without_hard_links(tmp_path: Path, monkeypatch, renameat2: bool) -> None:
    """A file system without hard links: renameat2(RENAME_NOREPLACE), else a check just
    before the rename; an existing file is still not replaced."""
    def no_link(source, target):
        raise OSError(errno.EPERM, os.strerror(errno.EPERM), source)

    monkeypatch.setattr(atomic.os, "link", no_link)
    if not renameat2:
        monkeypatch.setattr(atomic, "_renameat2_noreplace", lambda source, target: False)
    path = tmp_path / "out.txt"
    atomic_write_text(path, "ours", replace=False)
    assert path.read_text() == "ours"
    with pytest.raises(OutputExistsError):
        atomic_write_text(path, "again", replace=False)
    assert path.read_text() == "ours"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


def test_rename_no_replace_of_folders(tmp_path: Path) -> None:
    (tmp_path / "staging").mkdir()
    (tmp_path / "staging" / "sites.toml").write_text("x")
    (tmp_path / "target").mkdir()
    (tmp_path / "target" / "theirs").write_text("y")
    with pytest.raises(FileExistsError):
        rename_no_replace(tmp_path / "staging", tmp_path / "target")
    assert (tmp_path / "target" / "theirs").read_text() == "y"
    rename_no_replace(tmp_path / "staging", tmp_path / "new")
    assert (tmp_path / "new" / "sites.toml").read_text() == "x"


def test_publish_no_replace(tmp_path: Path) -> None:
    temporary = tmp_path / ".a.tmp"
    temporary.write_text("new")
    (tmp_path / "a").write_text("old")
    with pytest.raises(OutputExistsError):
        publish(temporary, tmp_path / "a", replace=False)
    assert (tmp_path / "a").read_text() == "old"
    publish(temporary, tmp_path / "a", replace=True)
    assert (tmp_path / "a").read_text() == "new"
    assert not temporary.exists()


@pytest.mark.parametrize(("code", "cause"), [
    (errno.ENOSPC, "disk full"), (errno.EFBIG, "file too large")])
def test_a_write_error_names_the_destination_and_leaves_nothing(tmp_path: Path, monkeypatch,
                                                                code: int, cause: str) -> None:
    def fsync(fd: int) -> None:
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(os, "fsync", fsync)
    path = tmp_path / "out.json"
    with pytest.raises(OSError) as caught:
        atomic_write_text(path, "x" * 1000)
    assert os_error_message(caught.value) == f"{path}: {cause}"
    assert list(tmp_path.iterdir()) == []


def test_arrow_errors_without_errno_are_understood(tmp_path: Path) -> None:
    error = OSError("Error writing bytes to file. Detail: [errno 28] No space left on device")
    assert os_error_message(error, tmp_path / "t.parquet") == f"{tmp_path / 't.parquet'}: disk full"
