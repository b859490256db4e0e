"""``SceneSearch``: type a sentence, get the moments; pick a moment, get more like it.

An index directory holds everything a search needs::

    INDEX_DIR/manifest.json     format version, model hash, dimensions, views, counts, created, paths,
                                checksums of the sub-manifests and run/config.json, and of its own content
    INDEX_DIR/fused/            ClipIndex (indexes/) of fused camera + BEV clip embeddings
    INDEX_DIR/camera/           ClipIndex of camera-only embeddings
    INDEX_DIR/bev/              ClipIndex of BEV-only embeddings
    INDEX_DIR/captions/         CaptionSearch: the clips' rule captions by the frozen sentence encoder
    INDEX_DIR/run/config.json   the model configuration (the weights stay in RUN_DIR, checked by hash)

>>> search = SceneSearch.build("run", "clips", "index")          # or SceneSearch.open("index")
>>> search.search_text("a car in the left lane approaches", k=5, filters={"category": "car"})
>>> search.search_clip("log:track:1700000000", k=5, view="bev")
>>> search.search_captions("stopped car")
>>> search.search_hybrid("a car cuts in front of us from the left")  # model and rule captions mixed
"""

from __future__ import annotations

import json
import shutil
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import asdict
from datetime import UTC, datetime
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from indexes.clip_index import ClipIndex
from indexes.errors import IndexesError
from indexes.filters import FilterSpec
from indexes.integrity import IntegrityWarning, Verify, VerifyLike, as_verify, file_entries, seal
from retrieval.embedding import CONFIG_FILE, Embedder, ModelEmbedder
from retrieval.errors import IndexDirError, ModelMismatchError, OtherMomentsError, UnknownClipError, UnknownViewError
from retrieval.hybrid import Scorers, WeightChoice, check_weight, choose_for_index
from retrieval.index_folder import INDEX_FOLDER
from retrieval.index_manifest import FORMAT_VERSION, KIND, MANIFEST, IndexManifest
from retrieval.index_parts import CAPTIONS_DIR, RUN_CONFIG, check_count, open_captions, verify_top_files
from retrieval.querying import (
    MAX_K,
    build_query,
    check_camera_clip,
    check_query,
    hits_to_results,
    moment_of,
    preview_of,
)
from retrieval.records import SearchResult
from retrieval.scenario_search import (
    SCENARIOS_DIR,
    ScenarioMatch,
    ScenarioStore,
    build_store,
    clip_log_folders,
    search_within,
)
from scenarios.cache import FEATURES_SUFFIX
from scenesearch_base.atomic import reading_directory
from scenesearch_base.folders import claim_folder, claimed_directory

if TYPE_CHECKING:
    from retrieval.captions_search import CaptionSearch, TextEncoder

VIEWS = ("fused", "camera", "bev")
Progress = Callable[[str], None]


class SceneSearch:
    """Text → clip, clip → clip and caption search over one index directory."""

    def __init__(self, index_dir: Path, manifest: IndexManifest, views: dict[str, ClipIndex],
                 captions: CaptionSearch | Callable[[], CaptionSearch], embedder: Embedder | None = None) -> None:
        """``captions``: the caption index, or what opens it when first used (:meth:`open`, ``lazy_captions``)."""
        self.index_dir = index_dir
        self.manifest = manifest
        self.views = views
        self._captions: CaptionSearch | None = None if callable(captions) else captions
        self._open_captions = captions if callable(captions) else None
        self._embedder = embedder
        self.clips_dir = Path(manifest.clips_dir)
        #: The weight of hybrid search (rule captions' share) and how it was chosen.
        self.hybrid = WeightChoice.from_json(manifest.hybrid)
        self._scorers = Scorers()
        #: Seconds spent in each step of the last ``search_text`` call (encode, search, records).
        self.last_timings_s: dict[str, float] = {}
        #: The scenario features of the index's logs, for scenario programs (:meth:`search_scenario`).
        self.scenarios = ScenarioStore(index_dir / SCENARIOS_DIR)

    # ------------------------------------------------------------------ building

    @classmethod
    def build(cls, run_dir: Path | str, clips_dir: Path | str, out_dir: Path | str,
              embedder: Embedder | None = None, text_encoder: TextEncoder | None = None,
              progress: Progress | None = None, hybrid_weight: float | None = None) -> SceneSearch:
        """Embed every clip (fused, camera-only, BEV-only) and its rule caption; write ``out_dir``.

        Args:
            run_dir: a training run (``model.safetensors`` + ``config.json``).
            clips_dir: the clips the run was trained on (``clips.parquet`` + per-log arrays).
            out_dir: the index directory; replaced atomically when it is an index folder
                (:mod:`scenesearch_base.folders`), refused when it is another folder or one of the inputs.
            embedder: the model (default: :class:`ModelEmbedder` of ``run_dir``).
            text_encoder: the sentence encoder of the caption index (default: all-MiniLM-L6-v2, seeded with
                the run's own text cache, :meth:`SentenceEncoder.for_run`).
            progress: called with one line per step.
            hybrid_weight: the weight of hybrid search (default: chosen on the validation clips).

        Raises:
            FileNotFoundError: no model in ``run_dir`` or no ``clips.parquet`` in ``clips_dir``.
        """
        from encoders.clips.layout import read_clip_table
        from retrieval.captions_search import CaptionSearch, Skipped, caption_rows
        from retrieval.sentence_encoder import SentenceEncoder

        say = progress or (lambda _m: None)
        run_dir, clips_dir, out_dir = Path(run_dir).resolve(), Path(clips_dir).resolve(), Path(out_dir)
        claim_folder(out_dir, INDEX_FOLDER, (run_dir, clips_dir), whole=True)  # before hours of embedding
        embedder = embedder if embedder is not None else ModelEmbedder(run_dir)
        rows, skipped = caption_rows(read_clip_table(clips_dir))
        clip_ids = rows.column("clip_id").to_pylist()
        views: dict[str, ClipIndex] = {}
        dim = 0
        for view in VIEWS:
            start = time.perf_counter()
            ids, x = embedder.embed_clips(clips_dir, view=view)
            x_view, kept = _align(clip_ids, ids, x)
            meta = rows.select([c for c in rows.column_names if c not in ("canonical_caption", "paraphrases")])
            table = meta.filter(pa.array(kept)) if not kept.all() else meta
            if not kept.all():
                skipped.extend(Skipped(c, f"the model gave no {view} embedding")
                               for c, keep in zip(clip_ids, kept) if not keep)
            views[view] = ClipIndex.build(x_view, table, metric="cosine")
            dim = int(x_view.shape[1])
            say(f"index: embedded {len(x_view)} clips, view {view} ({x_view.shape[1]}-D) in "
                f"{time.perf_counter() - start:.1f} s")
        start = time.perf_counter()
        sentence = text_encoder if text_encoder is not None else SentenceEncoder.for_run(run_dir)
        captions = CaptionSearch.build(rows, encoder=sentence, base_dir=clips_dir)
        say(f"index: embedded {len(captions)} rule captions in {time.perf_counter() - start:.1f} s")
        hybrid = choose_for_index(rows, views["fused"], captions, embedder.embed_texts, given=hybrid_weight)
        say(f"index: hybrid weight {hybrid.weight:g} (rule captions' share), {hybrid.origin}")
        split_counts: dict[str, int] = {}
        if "split" in rows.column_names:
            for s in rows.column("split").to_pylist():
                split_counts[f"split_{s}"] = split_counts.get(f"split_{s}", 0) + 1
        with claimed_directory(out_dir, INDEX_FOLDER, (run_dir, clips_dir)) as tmp:
            for view, index in views.items():
                index.save(tmp / view)
            captions.save(tmp / CAPTIONS_DIR)
            (tmp / "run").mkdir()
            folders = clip_log_folders(clips_dir)
            scenarios = build_store(tmp / SCENARIOS_DIR, folders,
                                    rows.column("log_id").to_pylist() if folders else ())
            say(f"index: scenario features of {scenarios['logs']} log(s)"
                + (f", {len(scenarios['missing'])} missing" if scenarios["missing"] else ""))
            for log_id, reason in list(scenarios["missing"].items())[:20]:
                say(f"note: no scenario features for log {log_id}: {reason}")
            covered = [f"{d}/{MANIFEST}" for d in (*VIEWS, CAPTIONS_DIR)]
            covered += [f"{SCENARIOS_DIR}/{p.name}" for p in sorted((tmp / SCENARIOS_DIR).glob(f"*{FEATURES_SUFFIX}"))]
            if (run_dir / CONFIG_FILE).is_file():
                shutil.copy2(run_dir / CONFIG_FILE, tmp / "run" / CONFIG_FILE)
                covered.append(RUN_CONFIG)
            manifest = IndexManifest(
                format_version=FORMAT_VERSION, kind=KIND, model_sha256=embedder.model_id, run_dir=str(run_dir),
                clips_dir=str(clips_dir), embed_dim=dim, views=list(VIEWS),
                counts={**{v: len(ix) for v, ix in views.items()}, "captions": len(captions), **split_counts},
                text_encoder=captions.encoder_name, created=datetime.now(UTC).isoformat(timespec="seconds"),
                skipped=[{"item": s.item, "reason": s.reason} for s in skipped],
                files={n: e.to_json() for n, e in file_entries(tmp, covered).items()}, hybrid=hybrid.to_json(),
                scenarios=scenarios)
            (tmp / MANIFEST).write_text(json.dumps(seal(asdict(manifest)), indent=2))
        say(f"index: wrote {out_dir} ({len(clip_ids)} clips, {len(skipped)} skipped)")
        return cls(out_dir, manifest, views, captions, embedder)

    @classmethod
    def open(cls, index_dir: Path | str, embedder: Embedder | None = None,
             text_encoder: TextEncoder | None = None, views: tuple[str, ...] = VIEWS,
             verify: VerifyLike = Verify.CACHED, lazy_captions: bool = False, mmap: bool = False) -> SceneSearch:
        """Open an index directory written by :meth:`build`, checking every file it reads.

        The model is loaded when the first text query needs it; its hash is checked then. A build
        killed while swapping directories is recovered here (see :mod:`scenesearch_base.atomic`).

        Args:
            index_dir: the index directory.
            embedder: the model of text queries (default: the run's, loaded on first use).
            text_encoder: the sentence encoder of caption search.
            views: the views to load.
            verify: file checksums: ``cached`` (hash files not verified before), ``full`` or
                ``off`` (warns once); see :mod:`indexes.integrity`.
            lazy_captions: open the caption index (and check its files) when a query first needs it,
                so that a process that ranks by the model or by clip alone never reads it (the CLI).
            mmap: map the views' vectors from disk instead of reading them (:meth:`ClipIndex.load`):
                a short-lived process touches only the pages a query reads; the views are read-only.

        Raises:
            IndexDirError: not an index directory, an unsupported format, or a missing, truncated
                or corrupt file (the message names it); with ``lazy_captions``, the caption index's
                files raise it when first used.
            ModelMismatchError: ``embedder`` is another model than the index was built with.
        """
        # Held until every file is read: a concurrent build of the same directory waits for it.
        with reading_directory(Path(index_dir)) as index_dir:
            manifest = IndexManifest.read(index_dir)
            if embedder is not None and embedder.model_id != manifest.model_sha256:
                raise ModelMismatchError(
                    f"index built by another model version: {index_dir} was built with model "
                    f"{manifest.model_sha256[:12]}, the given model is {embedder.model_id[:12]}")
            unknown = [v for v in views if v not in manifest.views]
            if unknown:
                raise UnknownViewError(unknown[0], manifest.views)
            mode = as_verify(verify)
            with warnings.catch_warnings():
                if mode is Verify.OFF:
                    warnings.warn(f"{index_dir}: checksums not verified (verify='off'); only file sizes were checked",
                                  IntegrityWarning, stacklevel=2)
                    warnings.filterwarnings("ignore", message=".*checksums not verified", category=IntegrityWarning)
                try:
                    verify_top_files(index_dir, manifest, (*views, *(() if lazy_captions else (CAPTIONS_DIR,))), mode)
                    loaded = {v: ClipIndex.load(index_dir / v, mmap=mmap, verify=mode) for v in views}
                except IndexesError as exc:
                    raise IndexDirError(str(exc)) from exc
                captions: CaptionSearch | Callable[[], CaptionSearch] = (
                    partial(open_captions, index_dir, manifest, text_encoder, mode, later=True) if lazy_captions
                    else open_captions(index_dir, manifest, text_encoder, mode))
        for name, size in ((v, len(ix)) for v, ix in loaded.items()):
            check_count(index_dir, manifest, name, size)
        return cls(index_dir, manifest, loaded, captions, embedder)

    @property
    def captions(self) -> CaptionSearch:
        """The clips' rule captions embedded by the frozen sentence encoder; opened on first use where the
        index was opened with ``lazy_captions``."""
        if self._captions is None:
            assert self._open_captions is not None
            self._captions = self._open_captions()
        return self._captions

    # ------------------------------------------------------------------ model

    @property
    def embedder(self) -> Embedder:
        """The model that encodes queries; loaded from the run directory on first use."""
        if self._embedder is None:
            run_dir = Path(self.manifest.run_dir)
            if not run_dir.is_dir():
                raise IndexDirError(f"the run directory {run_dir} of this index is gone; text queries need its "
                                    "model (clip → clip and caption search still work)")
            self._embedder = ModelEmbedder(run_dir, expected_model_id=self.manifest.model_sha256)
        return self._embedder

    # ------------------------------------------------------------------ queries

    def __len__(self) -> int:
        return len(next(iter(self.views.values())))

    @property
    def fields(self) -> list[str]:
        """Metadata fields that filters may name."""
        return [f for f in next(iter(self.views.values())).fields if f != "id"]

    def _view(self, view: str) -> ClipIndex:
        if view not in self.views:
            raise UnknownViewError(view, list(self.views))
        return self.views[view]

    def search_text(self, query: str, k: int = 10, filters: FilterSpec = None,
                    view: str = "fused", max_k: int = MAX_K) -> list[SearchResult]:
        """The k clips closest to the sentence ``query``.

        Args:
            query: a sentence, e.g. ``"a car in the left lane approaches, then stops"``.
            k: results, 1 … ``max_k`` (fewer when the index or the filter holds fewer clips).
            filters: ``{"category": "car"}``, ``{"category": ["car", "bus"]}`` or a filter string
                (``"category in {car, bus} and tags contains 'left:approach'"``, see ``indexes.filters``).
            view: ``fused``, ``camera`` or ``bev``; ``camera`` searches the clips the camera saw
                (:func:`retrieval.querying.build_query`).

        Raises:
            EmptyQueryError, InvalidKError, FilterSyntaxError, UnknownViewError: bad arguments.
            ModelMismatchError: the run directory now holds another model.
        """
        index = self._view(view)
        query = check_query(query)
        checked = build_query(k, filters, index.metadata, len(index), max_k, view)  # before the model loads
        t0 = time.perf_counter()
        xq = np.asarray(self.embedder.embed_texts([query]), dtype=np.float32)
        t1 = time.perf_counter()
        results = hits_to_results(index, xq, checked, view, self.clips_dir)
        t2 = time.perf_counter()
        self.last_timings_s = {"encode_text": t1 - t0, "search_and_records": t2 - t1}
        return results

    def search_clip(self, clip: str | Mapping[str, Any], k: int = 10, filters: FilterSpec = None,
                    view: str = "fused", max_k: int = MAX_K, other_moments: bool = False) -> list[SearchResult]:
        """The k clips most like ``clip``: an indexed clip id (left out of its own results) or clip arrays.

        Args:
            clip: a clip id, or a clip item / batch as ``encoders.data`` builds it (arrays of one clip).
            k, filters, view, max_k: as in :meth:`search_text`.
            other_moments: leave out the clips of the query's own moment, the other objects in view at the
                same time (its log, windows that share an instant with its own), which share its place, the ego's
                motion and the look: on the demo's test split they are many of the neighbours that differ
                in action (``docs/research/appearance-bias.md``). Needs a clip id; fewer than k come back
                when fewer clips are left.

        Raises:
            UnknownClipError: the clip id is not indexed (the message shows valid ones).
            NoCameraError: the camera view, from a clip id without camera frames.
            OtherMomentsError: ``other_moments`` with clip arrays, whose time window the index does not know.
        """
        index = self._view(view)
        if isinstance(clip, str):
            if clip not in index:
                examples = index.metadata.table.column("clip_id").slice(0, 3).to_pylist()
                raise UnknownClipError(clip, examples)
            row = index.get(clip)
            check_camera_clip(row, view)
            checked = build_query(k, filters, index.metadata, len(index) - 1, max_k, view)
            return hits_to_results(index, np.zeros((1, index.dim), np.float32), checked, view, self.clips_dir,
                                   exclude_clip=clip, exclude=moment_of(index, row) if other_moments else ())
        if other_moments:
            raise OtherMomentsError()
        checked = build_query(k, filters, index.metadata, len(index), max_k, view)
        xq = np.asarray(self.embedder.embed_arrays(clip, view=view), dtype=np.float32)[:1]
        return hits_to_results(index, xq, checked, view, self.clips_dir)

    def search_captions(self, query: str, k: int = 10, filters: FilterSpec = None,
                        max_k: int = MAX_K) -> list[SearchResult]:
        """Track-based search over the rule captions, with the frozen sentence encoder (no trained model)."""
        return self.captions.search(query, k, filters, max_k)

    def search_hybrid(self, query: str, k: int = 10, filters: FilterSpec = None, view: str = "fused",
                      weight: float | None = None, max_k: int = MAX_K) -> list[SearchResult]:
        """The k clips best by the model's and the rule captions' scores mixed (:mod:`retrieval.hybrid`);
        ``weight`` is the rule captions' share in [0, 1] (default: the index's, chosen on its validation
        clips; :class:`InvalidWeightError` outside), the rest as in :meth:`search_text`."""
        index = self._view(view)
        query = check_query(query)
        w = self.hybrid.weight if weight is None else check_weight(weight)
        checked = build_query(k, filters, index.metadata, len(index), max_k, view)
        scorer = self._scorers.get(view, index, self.captions)  # the first time: each clip's caption row
        t0 = time.perf_counter()
        xq = np.asarray(self.embedder.embed_texts([query]), dtype=np.float32)[0]
        rules = self.captions.scores(np.asarray(self.captions.encoder([query]), dtype=np.float32)[0])
        t1 = time.perf_counter()
        ids, scores = scorer.top_k(xq, rules, checked, w)
        results = [SearchResult.from_row(rank, row, float(score), view, preview_of(row, self.clips_dir))
                   for rank, (row, score) in enumerate(zip(index.metadata.rows(ids), scores), start=1)]
        self.last_timings_s = {"encode_text": t1 - t0, "search_and_records": time.perf_counter() - t1}
        return results

    def search_scenario(self, query: str, k: int = 10, filters: FilterSpec = None, view: str = "fused",
                        ranking: str = "model", weight: float | None = None, max_k: int = MAX_K, fill: bool = True
                        ) -> tuple[list[SearchResult], ScenarioMatch]:
        """The k moments the query's scenario program selects, ranked by ``ranking`` (``model``, ``hybrid``
        or ``captions``, as :meth:`search_text`, :meth:`search_hybrid`, :meth:`search_captions`); every
        moment when the query does not compile or its program selects none (the match says why). Where it
        selects fewer than k, the ranking's next best others follow (``fill``; :attr:`ScenarioMatch.filled`
        names them). See :mod:`retrieval.scenario_search`.

        Raises:
            ValueError: an unknown ``ranking``; the others as the ranking's own search raises them.
        """
        index = self._view(view)
        if ranking == "model":
            return search_within(self.scenarios, index.metadata, query, k, filters, max_k,
                                 lambda spec: self.search_text(query, k, spec, view, max_k), fill)
        if ranking == "hybrid":
            return search_within(self.scenarios, index.metadata, query, k, filters, max_k,
                                 lambda spec: self.search_hybrid(query, k, spec, view, weight, max_k), fill)
        if ranking == "captions":
            return search_within(self.scenarios, self.captions.metadata, query, k, filters, max_k,
                                 lambda spec: self.search_captions(query, k, spec, max_k), fill)
        raise ValueError(f"ranking {ranking!r}: one of model, hybrid, captions")

    def get(self, clip_id: str) -> SearchResult:
        """The record of one indexed clip (score 1, rank 0)."""
        index = next(iter(self.views.values()))
        if clip_id not in index:
            raise UnknownClipError(clip_id, index.metadata.table.column("clip_id").slice(0, 3).to_pylist())
        row = index.get(clip_id)
        return SearchResult.from_row(0, row, 1.0, next(iter(self.views)), preview_of(row, self.clips_dir))

    # ------------------------------------------------------------------ export

    def embeddings(self, view: str = "fused") -> tuple[pa.Table, np.ndarray]:
        """The metadata table (without ``id``) and the (N, D) embeddings of ``view``, in id order."""
        index = self._view(view)
        table = index.metadata.table
        x = index.vectors.reconstruct(np.asarray(table.column("id").to_numpy(), dtype=np.int64))
        return table.drop_columns(["id"]), np.asarray(x, dtype=np.float32)

    def export(self, path: Path | str, views: tuple[str, ...] | None = None) -> Path:
        """Write metadata and embeddings to ``path``: ``.parquet`` (one embedding column per view:
        ``embedding`` for the first, ``embedding_<view>`` for others) or ``.npy`` (+ ``.json`` beside it
        with the metadata rows, the view and the model hash). Written atomically.
        """
        import pyarrow.parquet as pq

        from scenesearch_base.atomic import atomic_path, atomic_write_text

        path = Path(path)
        views = views or tuple(self.views)
        for v in views:
            self._view(v)
        if path.suffix == ".parquet":
            table, _ = self.embeddings(views[0])
            for i, v in enumerate(views):
                meta, x = self.embeddings(v)
                if meta.column("clip_id").to_pylist() != table.column("clip_id").to_pylist():
                    raise IndexDirError(f"{self.index_dir}: views {views[0]} and {v} hold different clips")
                name = "embedding" if i == 0 else f"embedding_{v}"
                flat = pa.array(x.reshape(-1), pa.float32())
                table = table.append_column(name, pa.FixedSizeListArray.from_arrays(flat, x.shape[1]))
            meta_bytes = {b"scenesearch": json.dumps({"model_sha256": self.manifest.model_sha256,
                                                       "views": list(views)}).encode()}
            table = table.replace_schema_metadata({**(table.schema.metadata or {}), **meta_bytes})
            with atomic_path(path) as tmp:
                pq.write_table(table, tmp)
            return path
        if path.suffix == ".npy":
            meta, x = self.embeddings(views[0])
            with atomic_path(path) as tmp:
                np.save(tmp, x)
            sidecar = path.with_suffix(".json")
            atomic_write_text(sidecar, json.dumps({"view": views[0], "model_sha256": self.manifest.model_sha256,
                                                   "rows": meta.to_pylist()}, indent=1, default=str))
            return path
        raise ValueError(f"{path}: unknown export format {path.suffix!r}; use .parquet or .npy")


def _align(clip_ids: list[str], ids: list[str], x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``x`` (labelled ``ids``) in the order of ``clip_ids``; (M, D) and the (N,) kept mask."""
    pos = {c: i for i, c in enumerate(ids)}
    kept = np.array([c in pos for c in clip_ids], dtype=bool)
    order = [pos[c] for c in clip_ids if c in pos]
    if not order:
        raise ValueError("the model embedded none of the clips of the clip table")
    return np.asarray(x, dtype=np.float32)[order], kept
