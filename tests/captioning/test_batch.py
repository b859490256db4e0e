"""Captioning many log folders: each log's captions written as they come, in the input order, to the
same files as captioning them all first."""

from __future__ import annotations

from pathlib import Path

import pyarrow.parquet as pq

from captioning.batch import caption_logs
from captioning.outputs import write_outputs
from captioning.pipeline import CAPTIONS_FILENAME, FRAME_TAGS_FILENAME, LOGS_FILENAME, LogCaptions
from retrieval.cli import main
from tests.encoders.clip_fixtures import write_synthetic_log


def test_logs_written_as_they_come_give_the_files_of_all_logs_written_at_once(tmp_path: Path) -> None:
    logs = [write_synthetic_log(tmp_path / "logs", log_id=f"log_{i}", num_frames=30, seed=i) for i in range(3)]
    (tmp_path / "logs" / "empty").mkdir()  # not a log: skipped, and never written
    given = [*logs, tmp_path / "logs" / "empty"]
    whole = caption_logs(given)
    written: list[LogCaptions] = []
    streamed = caption_logs(given, write=written.append)
    assert [r.log_id for r in written] == [r.log_id for r in whole.results] == [p.name for p in logs]
    assert streamed.results == [] and streamed.summaries == whole.summaries
    assert streamed.skipped_logs == whole.skipped_logs and len(whole.skipped_logs) == 1
    assert [s.captions for s in whole.summaries] == [len(r.captions) for r in whole.results]

    write_outputs(tmp_path / "at_once", whole.results, logs)
    assert main(["caption", *map(str, given), "--out", str(tmp_path / "as_they_come")]) == 1  # one skipped
    for name in (FRAME_TAGS_FILENAME, CAPTIONS_FILENAME):
        assert pq.read_table(tmp_path / "as_they_come" / name).equals(pq.read_table(tmp_path / "at_once" / name))
    assert (tmp_path / "as_they_come" / LOGS_FILENAME).read_text() == (tmp_path / "at_once" / LOGS_FILENAME).read_text()
