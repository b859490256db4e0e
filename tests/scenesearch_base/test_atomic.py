"""Atomic writes: temporary names, stale entries of killed writes, and directory swaps killed half way."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

import scenesearch_base.atomic as atomic
from scenesearch_base.atomic import (
    aside_path,
    atomic_directory,
    atomic_path,
    atomic_write_text,
    machine_tag,
    reading_directory,
    recover_directory,
    scratch_path,
    sweep_stale,
)

ROOT = Path(__file__).resolve().parents[2]


def _dead_pid() -> int:
    """The pid of a process that has exited (and been reaped)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait(timeout=30)
    return child.pid


def _age(path: Path, seconds: float) -> None:
    t = time.time() - seconds
    os.utime(path, (t, t))


def test_temporary_names_carry_pid_and_machine(tmp_path: Path) -> None:
    with atomic_path(tmp_path / "a.parquet") as tmp:
        assert tmp.name.startswith(f".a.parquet.{os.getpid()}@{machine_tag()}.")
        assert tmp.name.endswith(".tmp.parquet")
        tmp.write_text("x")
    with atomic_directory(tmp_path / "d") as tmp_dir:
        assert tmp_dir.name.startswith(f".d.{os.getpid()}@{machine_tag()}.")
        (tmp_dir / "f").write_text("y")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.parquet", "d"]


def test_a_scratch_file_is_a_temporary_entry_removed_when_its_block_ends(tmp_path: Path) -> None:
    """Room for what a writer spools beside its output: never content of the folder, gone after the
    block (raised or not), and swept by the next write when its writer was killed."""
    with scratch_path(tmp_path / "clips.parquet") as spool:
        assert spool.parent == tmp_path and spool.name.startswith(f".clips.parquet.{os.getpid()}@{machine_tag()}.")
        spool.write_text("rows")
        assert atomic.is_temporary(spool.name)
    assert not spool.exists()
    with pytest.raises(RuntimeError), scratch_path(tmp_path / "clips.parquet") as spool:
        spool.write_text("rows")
        raise RuntimeError("the run stops")
    assert list(tmp_path.iterdir()) == []
    killed = tmp_path / f".clips.parquet.{_dead_pid()}@{machine_tag()}.abcd_123.tmp.parquet"
    killed.write_text("rows of a killed run")
    atomic.sweep_stale(tmp_path, force=True)
    assert not killed.exists()


def test_next_write_removes_stale_entries_only(tmp_path: Path) -> None:
    dead, me, other = _dead_pid(), os.getpid(), "0123abcd" if machine_tag() != "0123abcd" else "fedc3210"
    stale = [
        tmp_path / f".x.parquet.{dead}@{machine_tag()}.abcd_123.tmp.parquet",  # killed writer, this machine
        tmp_path / f".idx.{dead}@{machine_tag()}.k2j3h4g5.tmp",  # killed directory write
        tmp_path / f".y.json.1234@{other}.zzzzzzzz.tmp.json",  # another machine, two days old
        tmp_path / ".z.json.q1w2e3r4.tmp.json",  # older version's name (no pid), two days old
    ]
    kept = [
        tmp_path / f".live.json.{me}@{machine_tag()}.aaaaaaaa.tmp.json",  # a writer still running
        tmp_path / f".fresh.json.1234@{other}.bbbbbbbb.tmp.json",  # another machine, recent
        tmp_path / ".w.json.q1w2e3r4.tmp.json",  # older version's name, recent
        tmp_path / ".notes.tmp",  # not ours
        tmp_path / f".idx.{dead}@{machine_tag()}.old",  # not a temporary name
    ]
    for p in stale + kept:
        if p.name.startswith(".idx"):
            p.mkdir()
            (p / "index.faiss").write_bytes(b"half")
        else:
            p.write_text("half")
    for p in (stale[2], stale[3]):
        _age(p, 2 * 86400)
    atomic.sweep_stale(tmp_path, force=True)  # reset this process's sweep clock for the folder
    for p in stale:
        assert p.exists() is False, p.name
    for p in kept:
        assert p.exists(), p.name
    # A write sweeps on its own: a new stale entry goes with the next write (interval forced to 0 here).
    again = tmp_path / f".x.parquet.{dead}@{machine_tag()}.eeeeeeee.tmp.parquet"
    again.write_text("half")
    atomic.SWEEP_INTERVAL_S, old_interval = 0.0, atomic.SWEEP_INTERVAL_S
    try:
        atomic_write_text(tmp_path / "other.txt", "new")
    finally:
        atomic.SWEEP_INTERVAL_S = old_interval
    assert not again.exists()


def test_sweeps_are_rate_limited_per_folder(tmp_path: Path) -> None:
    assert sweep_stale(tmp_path, force=True) == []
    stale = tmp_path / f".a.{_dead_pid()}@{machine_tag()}.abcdefgh.tmp"
    stale.write_text("half")
    assert sweep_stale(tmp_path) == []  # swept a moment ago
    assert stale.exists()
    assert sweep_stale(tmp_path, force=True) == [stale]


def test_recover_directory_moves_the_aside_copy_back(tmp_path: Path) -> None:
    target = tmp_path / "index"
    aside = aside_path(target)
    aside.mkdir()
    (aside / "manifest.json").write_text("{}")
    assert recover_directory(target) == target
    assert (target / "manifest.json").read_text() == "{}" and not aside.exists()
    assert recover_directory(tmp_path / "nothing") == tmp_path / "nothing"


def test_recover_directory_reads_the_aside_copy_where_it_cannot_move_it(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "index"
    aside_path(target).mkdir()

    def read_only(src: object, dst: object) -> None:
        raise PermissionError("read-only file system")

    monkeypatch.setattr(os, "replace", read_only)
    assert recover_directory(target) == aside_path(target)


def test_a_reader_waits_for_a_swap_in_progress(tmp_path: Path) -> None:
    target = tmp_path / "index"
    aside_path(target).mkdir()
    result: list[Path] = []
    with atomic._folder_lock(tmp_path) as locked:  # a writer between its two renames
        assert locked
        reader = threading.Thread(target=lambda: result.append(recover_directory(target)))
        reader.start()
        reader.join(0.3)
        assert reader.is_alive() and not target.exists()  # it neither guessed nor moved anything
        aside_path(target).rename(target)  # the writer finishes its swap
    reader.join(10)
    assert result == [target]


def test_a_swap_waits_for_a_reader_and_the_reader_sees_one_version(tmp_path: Path) -> None:
    target = tmp_path / "index"
    with atomic_directory(target) as tmp:
        (tmp / "a").write_text("1")
        (tmp / "b").write_text("1")
    swapped = threading.Event()

    def write() -> None:
        with atomic_directory(target, overwrite=True) as tmp:
            (tmp / "a").write_text("2")
            (tmp / "b").write_text("2")
        swapped.set()

    with reading_directory(target) as directory:
        assert directory == target
        first = (directory / "a").read_text()
        writer = threading.Thread(target=write)
        writer.start()
        assert not swapped.wait(0.3)  # the new version is complete, but its swap waits for the read
        assert (directory / "b").read_text() == first == "1"
    writer.join(10)
    assert swapped.is_set() and (target / "a").read_text() == "2"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["index"]


def test_reading_directory_reads_the_aside_copy_of_a_killed_swap(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "index"
    aside_path(target).mkdir()
    (aside_path(target) / "v").write_text("old")
    monkeypatch.setattr(atomic, "recover_directory", lambda t: t)  # a read-only folder: nothing moved
    with reading_directory(target) as directory:
        assert directory == aside_path(target) and (directory / "v").read_text() == "old"


def test_next_write_finishes_an_interrupted_swap(tmp_path: Path) -> None:
    target = tmp_path / "out"
    aside_path(target).mkdir()
    (aside_path(target) / "v").write_text("1")
    # The previous directory is back, so this is no new target.
    with pytest.raises(FileExistsError), atomic_directory(target):
        pass
    assert (target / "v").read_text() == "1"
    # A stale aside copy beside a complete target (a kill after the second rename) is garbage.
    aside_path(target).mkdir()
    with atomic_directory(target, overwrite=True) as tmp:
        (tmp / "v").write_text("2")
    assert (target / "v").read_text() == "2"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


_KILLED_SWAP = textwrap.dedent("""
    import os, signal, sys
    from pathlib import Path
    sys.path[:0] = [{root!r}, {here!r}]
    import kill_points
    from scenesearch_base.atomic import atomic_directory, atomic_path
    target, point = Path({target!r}), {point!r}
    kill_points.install(target, point)
    if point == "file_write":
        with atomic_path(target.parent / "table.parquet") as tmp:
            tmp.write_bytes(b"half")
            kill_points.die()
    with atomic_directory(target, overwrite=True) as tmp:
        (tmp / "v").write_text("new")
        if point == "writing":
            kill_points.die()
""")


@pytest.mark.parametrize("point", ["file_write", "writing", "before_swap", "between_renames", "after_swap"])
def test_kill_at_each_point_of_a_swap(tmp_path: Path, point: str) -> None:
    target = tmp_path / "out"
    with atomic_directory(target) as tmp:
        (tmp / "v").write_text("old")
    code = _KILLED_SWAP.format(root=str(ROOT), here=str(Path(__file__).parent), target=str(target), point=point)
    child = subprocess.run([sys.executable, "-c", code], timeout=60)
    assert child.returncode == -signal.SIGKILL
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "out"]
    assert leftovers, "the kill left nothing behind to clean up"
    expected = "new" if point == "after_swap" else "old"
    assert (recover_directory(target) / "v").read_text() == expected
    # The next write into the folder (a new process) removes the temporary entries the killed one
    # left; an aside copy left after the second rename goes with the next write of its target.
    sweep_stale(tmp_path, force=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ([".out.old"] if point == "after_swap" else []) + ["out"]
    with atomic_directory(target, overwrite=True) as tmp:
        (tmp / "v").write_text("next")
    assert (target / "v").read_text() == "next"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
