from pathlib import Path

import numpy as np
import pytest

from indexes.errors import IdError, IndexFileError, MetadataError
from indexes.metadata import MetadataStore


def store() -> MetadataStore:
    rows = [{"clip_id": f"c{i}", "category": "car" if i % 2 else "truck", "tags": [f"t{i}"]} for i in range(5)]
    return MetadataStore.from_rows(rows, np.array([40, 10, 30, 0, 20]))


def test_rows_are_sorted_by_id_and_looked_up_both_ways() -> None:
    s = store()
    assert s.ids.tolist() == [0, 10, 20, 30, 40]
    assert s.clip_ids(np.array([40, 0])) == ["c0", "c3"]
    assert s.ids_of(["c1", "c4"]).tolist() == [10, 20]
    assert s.rows(np.array([30]))[0] == {"id": 30, "clip_id": "c2", "category": "truck", "tags": ["t2"]}
    assert s.select("category == car").tolist() == [0, 10]  # c3 and c1
    with pytest.raises(IdError, match="no metadata row.*5"):
        s.rows(np.array([5]))
    with pytest.raises(MetadataError, match="unknown clip ids"):
        s.ids_of(["zz"])


def test_append_remove_and_parquet_round_trip(tmp_path: Path) -> None:
    s = store()
    s.append([{"clip_id": "new", "category": "bus", "tags": [], "night": True}], np.array([50]))
    assert s.rows(np.array([50]))[0]["night"] is True and s.rows(np.array([0]))[0]["night"] is None
    s.remove(np.array([10, 20]))
    assert s.ids.tolist() == [0, 30, 40, 50]
    s.write(tmp_path / "m.parquet")
    back = MetadataStore.read(tmp_path / "m.parquet")
    assert back.table.equals(s.table)
    (tmp_path / "bad.parquet").write_bytes(b"not parquet")
    with pytest.raises(IndexFileError, match="bad.parquet"):
        MetadataStore.read(tmp_path / "bad.parquet")


def test_bad_rows() -> None:
    with pytest.raises(MetadataError, match="row 1, field 'clip_id'"):
        MetadataStore.from_rows([{"clip_id": "a"}, {"clip_id": ""}], np.array([0, 1]))
    with pytest.raises(MetadataError, match="duplicate clip ids.*'a'"):
        MetadataStore.from_rows([{"clip_id": "a"}, {"clip_id": "a"}], np.array([0, 1]))
    with pytest.raises(MetadataError, match="row 0"):
        MetadataStore.from_rows(["not a dict"], np.array([0]))  # type: ignore[list-item]
