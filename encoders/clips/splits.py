"""Train / val / test splits by log, never by clip, so that no log leaks across splits."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable

from encoders.clips.config import Split, SplitConfig


def log_hash_unit(seed: int, log_id: str) -> float:
    """A deterministic number in [0, 1) from ``(seed, log_id)``."""
    digest = hashlib.sha256(f"{int(seed)}:{log_id}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


def assign_splits(log_ids: Iterable[str], config: SplitConfig) -> dict[str, Split]:
    """Split logs by a seeded hash of their id; the logs in ``config.train_only`` train, those in
    ``config.val_only`` validate and those in ``config.test_only`` are held out for test.

    A log's split depends only on ``(seed, log_id)``, so adding logs never moves the others —
    except that with three or more (hashed) logs every split gets at least one: when a split is
    empty, the logs whose hash lies nearest to it are moved into it.
    """
    all_ids = set(log_ids)
    forced = {log_id: split for log_id, split in sorted(config.forced().items()) if log_id in all_ids}
    return forced | _hash_splits(sorted(all_ids - forced.keys()), config)


def _hash_splits(ids: list[str], config: SplitConfig) -> dict[str, Split]:
    unit = {log_id: log_hash_unit(config.seed, log_id) for log_id in ids}
    cut_train = config.train_fraction
    cut_val = config.train_fraction + config.val_fraction

    def pick(u: float) -> Split:
        return Split.TRAIN if u < cut_train else Split.VAL if u < cut_val else Split.TEST

    splits = {log_id: pick(u) for log_id, u in unit.items()}
    if len(ids) < 3:
        return splits
    wanted = [Split.TEST] + ([Split.VAL] if config.val_fraction > 0 else []) + [Split.TRAIN]
    by_unit = sorted(ids, key=lambda i: unit[i])
    for split in wanted:
        if split in splits.values():
            continue
        counts = {s: sum(1 for v in splits.values() if v == s) for s in Split}
        # Take from the largest split the log whose hash is nearest this split's range.
        donor = max(counts, key=lambda s: counts[s])
        candidates = [i for i in by_unit if splits[i] == donor]
        target = {Split.TRAIN: 0.0, Split.VAL: 0.5 * (cut_train + cut_val), Split.TEST: 1.0}[split]
        chosen = min(candidates, key=lambda i: (abs(unit[i] - target), i))
        splits[chosen] = split
    return splits
