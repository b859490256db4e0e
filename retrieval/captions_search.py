"""Search over rule captions alone: works on any log with tracks, including real logs without sensors.

Every caption row (an object over a time window, or the host vehicle) is described by two groups
of texts: the *full* texts — its canonical caption and captioning's paraphrases of it, host sentence
included — and the *object* texts — for a neighbour the same texts without the host's sentence (what
the object itself does); a host row's object texts are its full texts. Each distinct text is
embedded once by the frozen sentence encoder (:class:`retrieval.sentence_encoder.SentenceEncoder`, no
trained model), a text of several sentences as the mean of its sentences, as the index's manifest
records (``whole_text``), and the queries alike. A row scores the mean of its best full-text and
best object-text cosine similarity to the query, so "stopped car" meets "A car in the left lane is
stopped." (a paraphrase, object part) ahead of "The ego vehicle is stopped. A car … approaches." (the
host stopped, not the car), while "the ego vehicle stops" still finds the host's own rows.

>>> search = CaptionSearch.build("captions/captions.parquet", "captions_index")
>>> search.search("stopped car", k=5, filters={"category": "car"})

:mod:`retrieval.logs_search` captions log folders and searches them in one call (tracks only).

Directory layout (written atomically)::

    manifest.json         kind caption_search, format version, text encoder and how it embeds a text of
                          several sentences (``whole_text``, :class:`SentenceEncoder`), counts, skipped rows,
                          each file's size and SHA-256, and the checksum of its own content
    metadata.parquet      one row per moment (id, clip_id, log_id, track_id, category, start_ns, …)
    texts.parquet         the distinct texts (column ``text``)
    text_embeddings.npy   (M, D) float32, L2-normalised, row i embeds texts[i]
    full_offsets.npy      (N + 1,) int64: row r's full texts are full_texts[offsets[r]:offsets[r + 1]]
    full_texts.npy        (V,) int64 indices into texts
    object_offsets.npy    (N + 1,) int64, object_texts.npy (W,): the same for the object texts
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from captioning.pipeline import CAPTIONS_FILENAME
from captioning.tables import BEHAVIOR_CAPTION_FIELDS
from captioning.text import OBJECT_HALF, caption_halves
from encoders.clips.layout import clip_id
from encoders.config import WHOLE_TEXT_KINDS
from indexes.errors import IndexesError, IndexFileError, ManifestError
from indexes.filters import FilterSpec
from indexes.integrity import Verify, VerifyLike, file_entries, parse_file_entries, seal, verifying
from indexes.metadata import MetadataStore
from indexes.persistence import load_array, read_json_manifest
from retrieval.errors import IndexDirError
from retrieval.index_folder import INDEX_FOLDER
from retrieval.querying import MAX_K, build_query, check_query, preview_of
from retrieval.records import SearchResult
from retrieval.scenario_search import (
    SCENARIOS_DIR,
    ScenarioMatch,
    ScenarioStore,
    build_store,
    log_folders_of,
    search_within,
)
from scenarios.cache import FEATURES_SUFFIX
from scenesearch_base.atomic import reading_directory, recover_directory
from scenesearch_base.folders import claim_folder, claimed_directory

if TYPE_CHECKING:
    from retrieval.sentence_encoder import SentenceEncoder
else:
    def __getattr__(name: str) -> Any:
        # SentenceEncoder is imported on first use (PEP 562): it imports torch, which reading an index's
        # manifest (through retrieval.hybrid) or a clip → clip search never needs.
        if name == "SentenceEncoder":
            from retrieval.sentence_encoder import SentenceEncoder

            globals()[name] = SentenceEncoder
            return SentenceEncoder
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

TextEncoder = Callable[[Sequence[str]], np.ndarray]
MANIFEST = "manifest.json"
KIND = "caption_search"
#: 2: the manifest lists every file's size and SHA-256 and holds the checksum of its own content.
FORMAT_VERSION = 2
METADATA_FILE = "metadata.parquet"
TEXTS_FILE = "texts.parquet"
EMBEDDINGS_FILE = "text_embeddings.npy"
FILES = (METADATA_FILE, TEXTS_FILE, EMBEDDINGS_FILE, "full_offsets.npy", "full_texts.npy", "object_offsets.npy",
         "object_texts.npy")
#: Columns kept as metadata (and filterable) when present in the caption table.
METADATA_COLUMNS = ("clip_id", "log_id", "track_id", "category", "start_ns", "end_ns", "caption", "tags",
                    "host_tags", "window", "split", "time_of_day", "weather", "has_camera", "preview_path",
                    *(f.name for f in BEHAVIOR_CAPTION_FIELDS))


@dataclass(frozen=True)
class Skipped:
    """An input left out of an index, and why."""

    item: str
    reason: str


def caption_rows(table: pa.Table) -> tuple[pa.Table, list[Skipped]]:
    """The metadata table of a caption (or clip) table: one row per unique moment with a caption.

    Adds ``clip_id`` (:func:`encoders.clips.layout.clip_id`) when absent; drops rows without a caption,
    rows that end before they start, and repeated ids (each reported). Keeps ``paraphrases`` and
    ``canonical_caption`` for :func:`text_variants` (they are not metadata).
    """
    missing = [c for c in ("log_id", "track_id", "start_ns", "caption") if c not in table.column_names]
    if "caption" in missing and "canonical_caption" in table.column_names:
        table = table.append_column("caption", table.column("canonical_caption"))
        missing.remove("caption")
    if missing:
        raise ValueError(f"the caption table lacks the columns {missing}; it has {table.column_names}")
    if "clip_id" not in table.column_names:
        ids = [clip_id(lg, tr, st) for lg, tr, st in zip(table.column("log_id").to_pylist(),
                                                         table.column("track_id").to_pylist(),
                                                         table.column("start_ns").to_pylist())]
        table = table.append_column("clip_id", pa.array(ids, pa.string()))
    keep = [c for c in (*METADATA_COLUMNS, "canonical_caption", "paraphrases") if c in table.column_names]
    table = table.select(keep)
    skipped: list[Skipped] = []
    seen: set[str] = set()
    mask = np.zeros(table.num_rows, dtype=bool)
    starts = table.column("start_ns").to_pylist()
    ends = table.column("end_ns").to_pylist() if "end_ns" in table.column_names else starts
    for i, (cid, cap) in enumerate(zip(table.column("clip_id").to_pylist(), table.column("caption").to_pylist())):
        if not cap or not str(cap).strip():
            skipped.append(Skipped(str(cid), "no caption"))
        elif starts[i] is None or ends[i] is None or ends[i] < starts[i]:
            skipped.append(Skipped(str(cid), f"field 'end_ns' ({ends[i]}) is before field 'start_ns' ({starts[i]})"
                                   if starts[i] is not None and ends[i] is not None else "no start_ns or end_ns"))
        elif cid in seen:
            skipped.append(Skipped(str(cid), "repeated clip id (kept the first row)"))
        else:
            seen.add(cid)
            mask[i] = True
    return table.filter(pa.array(mask)), skipped


def is_caption_index(directory: Path | str) -> bool:
    """Whether ``directory`` holds a caption index written by :meth:`CaptionSearch.save`."""
    path = recover_directory(Path(directory)) / MANIFEST
    if not path.is_file():
        return False
    try:
        return bool(json.loads(path.read_text()).get("kind") == KIND)
    except (OSError, json.JSONDecodeError):
        return False


def text_variants(row: dict[str, Any]) -> tuple[list[str], list[str]]:
    """The full texts and the object texts that describe one caption row (see the module docstring)."""
    texts = [str(row["caption"])]
    if row.get("canonical_caption"):
        texts.append(str(row["canonical_caption"]))
    texts.extend(str(p) for p in (row.get("paraphrases") or []) if p)
    full = list(dict.fromkeys(t.strip() for t in texts if t.strip()))
    objects: list[str] = []
    if str(row.get("track_id")) != "ego":
        objects = list(dict.fromkeys(o for o in (caption_halves(t)[OBJECT_HALF] for t in full) if o))
    return full, objects or full


def _sentence_encoder_class() -> type[SentenceEncoder]:
    """The default sentence encoder's class, this module's ``SentenceEncoder`` (imported on first use)."""
    encoder_class: type[SentenceEncoder] = sys.modules[__name__].SentenceEncoder
    return encoder_class


class _Groups:
    """Rows → lists of text indices, as CSR arrays (offsets (N + 1,), indices (V,))."""

    def __init__(self, offsets: np.ndarray, indices: np.ndarray) -> None:
        self.offsets = np.asarray(offsets, dtype=np.int64)
        self.indices = np.asarray(indices, dtype=np.int64)

    @staticmethod
    def of(groups: Sequence[Sequence[str]], pos: dict[str, int]) -> _Groups:
        offsets = np.zeros(len(groups) + 1, dtype=np.int64)
        offsets[1:] = np.cumsum([len(g) for g in groups])
        return _Groups(offsets, np.asarray([pos[t] for g in groups for t in g], dtype=np.int64))

    def best(self, per_text: np.ndarray) -> np.ndarray:
        """(..., N) the best score among each row's texts, given (..., M) scores of all texts."""
        return np.asarray(np.maximum.reduceat(per_text[..., self.indices], self.offsets[:-1], axis=-1))

    def of_rows(self, rows: np.ndarray) -> _Groups:
        """The groups of rows ``rows`` (n,) alone, in that order (every row has at least one text)."""
        counts = self.offsets[rows + 1] - self.offsets[rows]
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        source = np.repeat(self.offsets[rows] - offsets[:-1], counts) + np.arange(offsets[-1])  # (V_n,)
        return _Groups(offsets, self.indices[source])


def _read_parts(directory: Path, counts: dict[str, Any]) -> tuple[MetadataStore, list[str], np.ndarray, _Groups,
                                                                   _Groups]:
    """Metadata, texts, (M, D) text embeddings and the two groups of a caption index, each checked.

    Raises:
        IndexFileError, MetadataError: a file that is unreadable or disagrees with the manifest's
            ``counts`` (``count`` rows, ``texts`` texts of ``dim`` dimensions) or with the others.
    """
    metadata = MetadataStore.read(directory / METADATA_FILE)
    if len(metadata) != counts["count"]:
        raise IndexFileError(directory / METADATA_FILE, f"holds {len(metadata)} rows, the manifest says "
                                                        f"{counts['count']}")
    texts_path = directory / TEXTS_FILE
    try:
        texts_table = pq.ParquetFile(texts_path).read()  # not read_table: it imports pyarrow.dataset
    except (OSError, pa.ArrowException) as exc:
        raise IndexFileError(texts_path, f"unreadable Parquet: {exc}") from None
    if "text" not in texts_table.column_names or not pa.types.is_string(texts_table.schema.field("text").type) \
            or texts_table.num_rows != counts["texts"] or texts_table.column("text").null_count:
        raise IndexFileError(texts_path, f"expected a string column 'text' of {counts['texts']} rows, got "
                                         f"{texts_table.schema} with {texts_table.num_rows} rows")
    texts = texts_table.column("text").to_pylist()
    emb = load_array(directory / EMBEDDINGS_FILE, np.float32, (len(texts), counts["dim"]))
    if not np.isfinite(emb).all():
        raise IndexFileError(directory / EMBEDDINGS_FILE, "holds NaN or infinite values")
    groups = []
    for name in ("full", "object"):
        offsets_path, texts_idx_path = directory / f"{name}_offsets.npy", directory / f"{name}_texts.npy"
        offsets = load_array(offsets_path, np.int64, (len(metadata) + 1,))
        indices = load_array(texts_idx_path, np.int64, ("V",))
        # Every row has at least one text, so offsets rise strictly (np.maximum.reduceat needs it).
        if offsets[0] != 0 or offsets[-1] != len(indices) or (np.diff(offsets) <= 0).any():
            raise IndexFileError(offsets_path, f"expected offsets rising strictly from 0 to {len(indices)} (the "
                                               f"length of {texts_idx_path.name}), got {offsets[:3].tolist()}… "
                                               f"ending at {int(offsets[-1])}")
        if len(indices) and (int(indices.min()) < 0 or int(indices.max()) >= len(texts)):
            raise IndexFileError(texts_idx_path, f"expected indices into the {len(texts)} texts, got values in "
                                                 f"[{int(indices.min())}, {int(indices.max())}]")
        groups.append(_Groups(offsets, indices))
    return metadata, texts, emb, groups[0], groups[1]


class CaptionSearch:
    """Rule captions embedded by a frozen sentence encoder, searchable by text."""

    def __init__(self, metadata: MetadataStore, texts: list[str], text_embeddings: np.ndarray,
                 full: _Groups, objects: _Groups, encoder: TextEncoder | None = None,
                 encoder_name: str | None = None, base_dir: Path | None = None,
                 skipped: Sequence[Skipped] = (), whole_text: str | None = None) -> None:
        self.metadata = metadata
        self.texts = texts
        self.text_embeddings = np.ascontiguousarray(text_embeddings, dtype=np.float32)
        self.full = full
        self.objects = objects
        self.encoder: TextEncoder = encoder if encoder is not None else _sentence_encoder_class()()
        self.encoder_name = str(encoder_name or getattr(self.encoder, "name", type(self.encoder).__name__))
        # How the texts were embedded (SentenceEncoder.whole_text): the queries have to be embedded alike.
        self.whole_text = whole_text or str(getattr(self.encoder, "whole_text", "text"))
        self.base_dir = base_dir
        self.skipped = list(skipped)
        #: The scenario features of the index's logs (none until opened from a directory that holds them).
        self.scenarios = ScenarioStore(None)
        #: Logs whose scenario features the last :meth:`save` could not store: log id → why.
        self.scenarios_missing: dict[str, str] = {}

    def __len__(self) -> int:
        return len(self.metadata)

    @property
    def fields(self) -> list[str]:
        """Metadata fields that filters may name."""
        return [f for f in self.metadata.fields if f != "id"]

    @classmethod
    def build(cls, captions: Path | str | pa.Table, out_dir: Path | str | None = None,
              encoder: TextEncoder | None = None, base_dir: Path | None = None) -> CaptionSearch:
        """Embed the captions of ``captions`` (a ``captions.parquet``, a captions directory, or a table).

        Each distinct text is embedded once. Written to ``out_dir`` atomically when given.

        Raises:
            FileNotFoundError: no caption table at the path.
            ValueError: the table lacks the caption columns or holds no captions.
        """
        if isinstance(captions, pa.Table):
            table = captions
        else:
            path = Path(captions)
            if path.is_dir():
                path = path / CAPTIONS_FILENAME
            if os.path.lexists(path) and not path.exists():  # a published generation's link left dangling
                raise FileNotFoundError(f"{path}: a broken link (to {os.readlink(path)}, which leads nowhere: "
                                        f"{path.resolve()} is missing); write the captions again")
            if not path.is_file():
                raise FileNotFoundError(f"{path}: no caption table here (run `scenesearch caption` first)")
            table = pq.read_table(path)
            base_dir = base_dir or path.parent
        if out_dir is not None:  # before the captions are embedded
            claim_folder(out_dir, INDEX_FOLDER, () if isinstance(captions, pa.Table) else (captions,), whole=True)
        rows, skipped = caption_rows(table)
        if rows.num_rows == 0:
            raise ValueError("no captions to index" + (f"; skipped: {skipped[:5]}" if skipped else ""))
        variants = [text_variants(r) for r in rows.to_pylist()]
        texts = list(dict.fromkeys(t for full, objects in variants for t in (*full, *objects)))
        pos = {t: i for i, t in enumerate(texts)}
        full_groups = _Groups.of([v[0] for v in variants], pos)
        object_groups = _Groups.of([v[1] for v in variants], pos)
        encoder = encoder if encoder is not None else _sentence_encoder_class()()
        embeddings = np.asarray(encoder(texts), dtype=np.float32)
        meta = rows.select([c for c in rows.column_names if c not in ("canonical_caption", "paraphrases")])
        store = MetadataStore.from_rows(meta, np.arange(rows.num_rows, dtype=np.int64))
        out = cls(store, texts, embeddings, full_groups, object_groups, encoder, None, base_dir, skipped)
        if out_dir is not None:
            folders = log_folders_of(base_dir) if base_dir is not None else {}
            out.save(out_dir, inputs=() if isinstance(captions, pa.Table) else (captions,), log_dirs=folders)
        return out

    def save(self, out_dir: Path | str, inputs: Sequence[Path | str] = (),
             log_dirs: Mapping[str, str] | None = None) -> None:
        """Write the directory described in the module docstring, atomically.

        ``out_dir`` is replaced only when it is an index folder (:mod:`scenesearch_base.folders`), and never when
        it is one of ``inputs``, lies inside one or holds one. With ``log_dirs`` (log id → folder) the
        index also holds its logs' scenario features (:mod:`retrieval.scenario_search`).
        """
        with claimed_directory(out_dir, INDEX_FOLDER, inputs) as tmp:
            log_ids = self.metadata.table.column("log_id").to_pylist() if log_dirs else ()
            scenarios = build_store(tmp / SCENARIOS_DIR, log_dirs, log_ids) if log_dirs else {}
            self.scenarios_missing = dict(scenarios.get("missing", {}))
            stored = [f"{SCENARIOS_DIR}/{p.name}" for p in sorted((tmp / SCENARIOS_DIR).glob(f"*{FEATURES_SUFFIX}"))]
            self.metadata.write(tmp / METADATA_FILE)
            pq.write_table(pa.table({"text": pa.array(self.texts, pa.string())}), tmp / TEXTS_FILE)
            np.save(tmp / EMBEDDINGS_FILE, self.text_embeddings)
            for name, groups in (("full", self.full), ("object", self.objects)):
                np.save(tmp / f"{name}_offsets.npy", groups.offsets)
                np.save(tmp / f"{name}_texts.npy", groups.indices)
            info = {"format_version": FORMAT_VERSION, "kind": KIND, "text_encoder": self.encoder_name,
                    "whole_text": self.whole_text,
                    "count": len(self), "texts": len(self.texts), "dim": int(self.text_embeddings.shape[1]),
                    "base_dir": None if self.base_dir is None else str(Path(self.base_dir).resolve()),
                    "skipped": [{"item": s.item, "reason": s.reason} for s in self.skipped],
                    "files": {n: e.to_json() for n, e in file_entries(tmp, [*FILES, *stored]).items()},
                    "scenarios": scenarios}
            (tmp / MANIFEST).write_text(json.dumps(seal(info), indent=2))

    @classmethod
    def open(cls, directory: Path | str, encoder: TextEncoder | None = None,
             verify: VerifyLike = Verify.CACHED) -> CaptionSearch:
        """Open a directory written by :meth:`save`, checking every file against the manifest.

        Args:
            directory: the caption index.
            encoder: the sentence encoder of queries (default: the one the index was built with).
            verify: file checksums: ``cached``, ``full`` or ``off`` (warns); see :mod:`indexes.integrity`.

        Raises:
            IndexDirError: not a caption index, an unsupported format, or a missing, corrupt or
                inconsistent file (the message names it and what was expected).
        """
        with reading_directory(Path(directory)) as directory:
            path = directory / MANIFEST
            if not path.is_file():
                raise IndexDirError(f"{path}: missing; {directory} is not a caption index (build one with "
                                    "CaptionSearch.build or `scenesearch index`)")
            try:
                info = read_json_manifest(path, KIND, FORMAT_VERSION)
                files = parse_file_entries(info.get("files"), path)
                if missing := [n for n in FILES if n not in files]:
                    raise ManifestError(path, f"does not list {', '.join(missing)}", field="files")
                counts = {k: info.get(k) for k in ("count", "texts", "dim")}
                for key, value in counts.items():
                    if not isinstance(value, int) or value < 0:
                        raise ManifestError(path, "missing or not a count", field=key)
                whole_text = info.get("whole_text")
                if whole_text is None:
                    raise ManifestError(path, "missing (built by an older version of scenesearch: build it again)",
                                        field="whole_text")
                if whole_text not in WHOLE_TEXT_KINDS:
                    raise ManifestError(path, f"must be one of {list(WHOLE_TEXT_KINDS)}, got {whole_text!r}",
                                        field="whole_text")
                with verifying(directory, files, verify):
                    parts = _read_parts(directory, counts)
            except IndexesError as exc:
                raise IndexDirError(str(exc)) from exc
        given = getattr(encoder, "whole_text", whole_text)
        if given != whole_text:  # queries embedded unlike the texts would rank by the difference
            raise IndexDirError(f"{path}, field 'whole_text': the index embedded its texts as {whole_text!r}, "
                                f"the given encoder embeds a text as {given!r}")
        encoder = encoder if encoder is not None else _sentence_encoder_class()(whole_text=whole_text)
        base = info.get("base_dir")
        out = cls(*parts, encoder, info.get("text_encoder"), Path(base) if base else None,
                  [Skipped(s["item"], s["reason"]) for s in info.get("skipped", [])], whole_text)
        out.scenarios = ScenarioStore(directory / SCENARIOS_DIR)
        return out

    def scores(self, xq: np.ndarray) -> np.ndarray:
        """(N,) score of every row for one query embedding (D,): mean of its best full and best object text."""
        # einsum, not @: a BLAS product this size wakes OpenBLAS's threads, whose spinning slows the text
        # encoders of the next query (see retrieval.hybrid).
        per_text = np.einsum("td,d->t", self.text_embeddings, np.asarray(xq, dtype=np.float32).reshape(-1))
        return np.asarray(0.5 * (self.full.best(per_text) + self.objects.best(per_text)))

    def scores_of(self, xq: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """(Q, n) :meth:`scores` of the rows ``rows`` (n,) for Q query embeddings (Q, D), reading only
        those rows' texts: the cost grows with the rows asked for, not with the index."""
        full, objects = self.full.of_rows(np.asarray(rows, np.int64)), self.objects.of_rows(np.asarray(rows, np.int64))
        used, at = np.unique(np.concatenate([full.indices, objects.indices]), return_inverse=True)
        full.indices, objects.indices = at[: len(full.indices)], at[len(full.indices):]
        per_text = np.asarray(xq, np.float32).reshape(len(xq), -1) @ self.text_embeddings[used].T  # (Q, U)
        return np.asarray(0.5 * (full.best(per_text) + objects.best(per_text)))

    def search(self, query: str, k: int = 10, filters: FilterSpec = None,
               max_k: int = MAX_K) -> list[SearchResult]:
        """The k moments whose captions are closest to ``query`` (fewer when a filter passes fewer).

        Raises:
            EmptyQueryError, InvalidKError, FilterSyntaxError: bad arguments (see :func:`build_query`).
        """
        query = check_query(query)
        checked = build_query(k, filters, self.metadata, len(self), max_k)
        xq = np.asarray(self.encoder([query]), dtype=np.float32)
        if xq.ndim != 2 or xq.shape[1] != self.text_embeddings.shape[1]:  # an index of another encoder
            query_encoder = getattr(self.encoder, "name", type(self.encoder).__name__)
            raise IndexDirError(f"the index's texts were embedded in {self.text_embeddings.shape[1]} dimensions "
                                f"(text encoder {self.encoder_name!r}); the query encoder {query_encoder!r} "
                                f"gives {xq.shape[-1]}: build the index again with this encoder")
        scores = self.scores(xq[0])
        if checked.filters is not None:
            allowed = np.zeros(len(self), dtype=bool)
            allowed[self.metadata.select(checked.filters)] = True
            scores = np.where(allowed, scores, -np.inf)
        k_eff = min(checked.k, int(np.isfinite(scores).sum()))
        if k_eff == 0:
            return []
        top = np.argpartition(-scores, k_eff - 1)[:k_eff]
        top = top[np.lexsort((top, -scores[top]))]
        rows = self.metadata.rows(top)
        return [SearchResult.from_row(rank, row, float(scores[i]), "captions", preview_of(row, self.base_dir))
                for rank, (i, row) in enumerate(zip(top, rows), start=1)]


    def search_scenario(self, query: str, k: int = 10, filters: FilterSpec = None, max_k: int = MAX_K,
                        fill: bool = True) -> tuple[list[SearchResult], ScenarioMatch]:
        """The k moments the query's scenario program selects, ranked by their captions' closeness to the
        query; every moment when it does not compile or selects none; where it selects fewer than k, the
        closest others after them (``fill``; see :mod:`retrieval.scenario_search`)."""
        return search_within(self.scenarios, self.metadata, query, k, filters, max_k,
                             lambda spec: self.search(query, k, spec, max_k), fill)
