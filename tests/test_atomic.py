"""Atomic writes behave like ordinary writes for modes and symlinks."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from agv_mission.atomic import atomic_write_text


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_an_existing_file_keeps_its_mode(tmp_path: Path) -> None:
    path = tmp_path / "shared.yaml"
    path.write_text("old\n")
    for mode in (0o644, 0o664, 0o600, 0o640):
        path.chmod(mode)
        atomic_write_text(path, "new\n")
        assert path.read_text() == "new\n"
        assert _mode(path) == mode


def test_a_new_file_honours_the_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        os.umask(0o002)
        atomic_write_text(tmp_path / "b.txt", "x")
    finally:
        os.umask(old)
    assert _mode(tmp_path / "a.txt") == 0o644
    assert _mode(tmp_path / "b.txt") == 0o664


def test_a_symlink_is_followed_and_stays_a_link(tmp_path: Path) -> None:
    target = tmp_path / "real" / "file.yaml"
    target.parent.mkdir()
    target.write_text("old\n")
    target.chmod(0o640)
    link = tmp_path / "link.yaml"
    link.symlink_to(target)
    chain = tmp_path / "chain.yaml"
    chain.symlink_to(link)
    written = atomic_write_text(chain, "new\n")
    assert written == target
    assert chain.is_symlink() and link.is_symlink()
    assert target.read_text() == "new\n" and _mode(target) == 0o640
    dangling = tmp_path / "dangling.yaml"
    dangling.symlink_to(tmp_path / "real" / "created.yaml")
    atomic_write_text(dangling, "made\n")
    assert dangling.is_symlink() and (tmp_path / "real" / "created.yaml").read_text() == "made\n"


def test_no_temporary_file_is_left_behind(tmp_path: Path) -> None:
    for i in range(5):
        atomic_write_text(tmp_path / "f.txt", str(i))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.txt"]
