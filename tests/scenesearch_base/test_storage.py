"""Locations that are local paths or pyarrow.fs URIs (tested with file:// URIs)."""

from __future__ import annotations

from pathlib import Path

import pytest

from scenesearch_base.storage import (
    as_location,
    exists,
    expand,
    is_uri,
    join,
    list_files,
    name_of,
    parent,
    read_bytes,
    remove_files,
    staged_input,
    staged_output,
    write_file,
)


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_paths_and_uris_are_told_apart() -> None:
    assert is_uri("s3://bucket/logs/a") and is_uri("file:///tmp/x") and is_uri("gs://b/c")
    assert not is_uri("logs/a") and not is_uri(Path("s3:/bucket")) and not is_uri("C:logs")
    assert as_location("s3://bucket/logs/") == "s3://bucket/logs/" and as_location("logs/a") == Path("logs/a")
    assert name_of("s3://bucket/logs/abc/") == "abc" and name_of(Path("logs/abc")) == "abc"
    assert join("s3://bucket/logs/", "a", "b.json") == "s3://bucket/logs/a/b.json"
    assert join(Path("logs"), "a") == Path("logs/a")
    assert parent("s3://bucket/captions/captions.parquet") == "s3://bucket/captions"
    assert parent("s3://bucket/captions/") == "s3://bucket"
    assert parent(Path("captions/captions.parquet")) == Path("captions")


def test_a_uri_folder_is_staged_in_and_out(tmp_path: Path) -> None:
    src = tmp_path / "store" / "logs" / "log_a"
    (src / "sensors" / "lidar").mkdir(parents=True)
    (src / "annotations.feather").write_bytes(b"\x00\x01annotations")
    (src / "sensors" / "lidar" / "1.feather").write_bytes(b"sweep")
    uri = f"file://{src}"
    with staged_input(uri) as local:
        assert local.name == "log_a" and local != src
        assert _tree(local) == _tree(src)
        staged_at = local
    assert not staged_at.exists()  # the temporary copy is removed
    with staged_input(src) as local:  # a local path is used as it is
        assert local == src
    out_uri = f"file://{tmp_path / 'store' / 'out'}"
    with staged_output(out_uri) as local:
        (local / "sub").mkdir()
        (local / "sub" / "table.parquet").write_bytes(b"table")
    assert (tmp_path / "store" / "out" / "sub" / "table.parquet").read_bytes() == b"table"
    assert read_bytes(f"{out_uri}/sub/table.parquet") == b"table"
    assert exists(f"{out_uri}/sub") and not exists(f"{out_uri}/nothing")


def test_a_failed_block_uploads_nothing(tmp_path: Path) -> None:
    out_uri = f"file://{tmp_path / 'out'}"
    with pytest.raises(RuntimeError), staged_output(out_uri) as local:
        (local / "half.parquet").write_bytes(b"half")
        raise RuntimeError("killed")
    assert not (tmp_path / "out").exists()


def test_a_prefix_expands_to_its_folders(tmp_path: Path) -> None:
    for name in ("b", "a", ".hidden"):
        (tmp_path / "logs" / name).mkdir(parents=True)
    (tmp_path / "logs" / "README").write_text("not a log")
    base = f"file://{tmp_path / 'logs'}"
    assert expand([f"{base}/*", "local/log"]) == [f"{base}/a", f"{base}/b", Path("local/log")]
    with pytest.raises(FileNotFoundError, match="no such folder"):
        expand([f"file://{tmp_path / 'none'}/*"])
    with pytest.raises(FileNotFoundError, match="not found"), staged_input(f"file://{tmp_path / 'none'}"):
        pass


@pytest.mark.parametrize("as_uri", [False, True])
def test_files_are_written_whole_listed_and_removed_by_pattern(tmp_path: Path, as_uri: bool) -> None:
    folder = tmp_path / "shards"
    location = f"file://{folder}" if as_uri else folder
    assert list_files(location, "part-*") == []  # no folder yet
    remove_files(location, "part-*")  # creates it
    assert folder.is_dir()
    for name in ("part-2.bin", "part-1.bin", "notes.txt"):
        write_file(join(location, name), lambda path, name=name: path.write_bytes(name.encode()))
    (folder / "part-sub").mkdir()  # a folder, not a file: never listed or removed
    assert list_files(location, "part-*") == [join(location, "part-1.bin"), join(location, "part-2.bin")]
    assert read_bytes(join(location, "part-2.bin")) == b"part-2.bin"
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt", "part-1.bin", "part-2.bin", "part-sub"]

    def fails(path: Path) -> None:
        path.write_bytes(b"half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError, match="killed"):
        write_file(join(location, "part-3.bin"), fails)
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt", "part-1.bin", "part-2.bin", "part-sub"]
    remove_files(location, "part-*")
    assert sorted(p.name for p in folder.iterdir()) == ["notes.txt", "part-sub"]  # the user's other files stay
