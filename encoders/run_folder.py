"""A training run's folder: what ``scenesearch train`` writes, claimed before the first file
(:mod:`scenesearch_base.folders`)."""

from __future__ import annotations

from pathlib import Path

from scenesearch_base.folders import FolderKind, claim_folder, mark_folder

RUN_FOLDER = FolderKind("run", signature="config.json", entries=(
    "config.json", "checkpoints", "metrics.jsonl", "metrics.json", "model.safetensors", "model_card.md",
    "text_cache.npz", "tagging.json", "tag_*", "tensorboard", "train.yaml", "trained_clips.json", "recipe.yaml"))


def claim_run_dir(run_dir: Path, clips_dir: Path | str) -> None:
    """Create ``run_dir`` as a run folder, or take an existing one.

    Raises:
        FolderClaimError: ``run_dir`` holds something else (an index, clips, a user's files), or is
            the clips folder, inside it or holding it.
    """
    claim_folder(run_dir, RUN_FOLDER, (clips_dir,))
    mark_folder(run_dir, RUN_FOLDER, RUN_FOLDER.entries)
