"""A BERT sentence encoder in plain torch: the all-MiniLM-L6-v2 family without sentence-transformers.

A sentence-transformers folder of the common shape (a BERT ``Transformer``, mean ``Pooling``, and
optionally ``Normalize``; ``model.safetensors``, ``tokenizer.json``) is loaded by :func:`load` with
``tokenizers`` and ``safetensors`` alone. Importing sentence-transformers (and with it transformers)
costs a command about 5 CPU-seconds before its first query; this module needs none of it and gives the
same embeddings (cosine 1.0000 on the demo's captions, tested against sentence-transformers).

Its parameters carry sentence-transformers' names (``0.model.encoder.layer.3.attention.self.query.weight``),
so a trained run's state dict loads into either, and its interface is the part of
``SentenceTransformer`` the towers use: ``preprocess``, ``forward(features)["sentence_embedding"]``,
``encode``, ``get_embedding_dimension`` and ``[0].auto_model.encoder.layer``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

#: The module types of the sentence-transformers folders this module reads.
_TRANSFORMER = "sentence_transformers.models.Transformer"
_POOLING = "sentence_transformers.models.Pooling"
_NORMALIZE = "sentence_transformers.models.Normalize"


class UnsupportedFolderError(ValueError):
    """A sentence-transformers folder of another shape (other modules, pooling or architecture)."""


@dataclass(frozen=True)
class BertConfig:
    vocab_size: int
    hidden_size: int
    num_hidden_layers: int
    num_attention_heads: int
    intermediate_size: int
    max_position_embeddings: int
    type_vocab_size: int
    layer_norm_eps: float
    hidden_dropout_prob: float
    attention_probs_dropout_prob: float


class _Linear(nn.Linear):
    """``nn.Linear`` without random initialisation: :func:`load` assigns every weight from the checkpoint,
    so drawing them first would be work thrown away at each start of a command."""

    def reset_parameters(self) -> None:
        pass


class _Embedding(nn.Embedding):
    """``nn.Embedding`` without random initialisation (see :class:`_Linear`): the 30,522-token table's
    normal draws were most of a query's model construction."""

    def reset_parameters(self) -> None:
        pass


class _Embeddings(nn.Module):
    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.word_embeddings = _Embedding(c.vocab_size, c.hidden_size, padding_idx=0)
        self.position_embeddings = _Embedding(c.max_position_embeddings, c.hidden_size)
        self.token_type_embeddings = _Embedding(c.type_vocab_size, c.hidden_size)
        self.LayerNorm = nn.LayerNorm(c.hidden_size, eps=c.layer_norm_eps)
        self.dropout = nn.Dropout(c.hidden_dropout_prob)

    def forward(self, ids: torch.Tensor, types: torch.Tensor) -> torch.Tensor:
        positions = torch.arange(ids.shape[1], device=ids.device)
        x = self.word_embeddings(ids) + self.position_embeddings(positions) + self.token_type_embeddings(types)
        return self.dropout(self.LayerNorm(x))  # (B, L, H)


class _SelfAttention(nn.Module):
    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.heads = c.num_attention_heads
        self.dropout_p = c.attention_probs_dropout_prob
        self.query = _Linear(c.hidden_size, c.hidden_size)
        self.key = _Linear(c.hidden_size, c.hidden_size)
        self.value = _Linear(c.hidden_size, c.hidden_size)

    def forward(self, x: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        b, n, h = x.shape
        q, k, v = (p(x).view(b, n, self.heads, h // self.heads).transpose(1, 2)  # (B, nh, L, hs)
                   for p in (self.query, self.key, self.value))
        out = F.scaled_dot_product_attention(q, k, v, attn_mask=bias,
                                             dropout_p=self.dropout_p if self.training else 0.0)
        return out.transpose(1, 2).reshape(b, n, h)  # (B, L, H)


class _DenseNorm(nn.Module):
    """A projection, dropout, and layer norm of the sum with the residual (BERT's ``*Output``)."""

    def __init__(self, c: BertConfig, width_in: int) -> None:
        super().__init__()
        self.dense = _Linear(width_in, c.hidden_size)
        self.LayerNorm = nn.LayerNorm(c.hidden_size, eps=c.layer_norm_eps)
        self.dropout = nn.Dropout(c.hidden_dropout_prob)

    def forward(self, x: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        return self.LayerNorm(self.dropout(self.dense(x)) + residual)


class _Attention(nn.Module):
    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.self = _SelfAttention(c)
        self.output = _DenseNorm(c, c.hidden_size)

    def forward(self, x: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        return self.output(self.self(x, bias), x)


class _Intermediate(nn.Module):
    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.dense = _Linear(c.hidden_size, c.intermediate_size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.gelu(self.dense(x))  # (B, L, I)


class _Layer(nn.Module):
    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.attention = _Attention(c)
        self.intermediate = _Intermediate(c)
        self.output = _DenseNorm(c, c.intermediate_size)

    def forward(self, x: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        x = self.attention(x, bias)
        return self.output(self.intermediate(x), x)


class _Encoder(nn.Module):
    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.layer = nn.ModuleList(_Layer(c) for _ in range(c.num_hidden_layers))


class _Pooler(nn.Module):
    """BERT's [CLS] pooler: unused by mean pooling, kept so that the checkpoint's keys all have a home."""

    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.dense = _Linear(c.hidden_size, c.hidden_size)


class BertModel(nn.Module):
    """Token embeddings of a BERT encoder: (B, L) ids → (B, L, H)."""

    def __init__(self, c: BertConfig) -> None:
        super().__init__()
        self.config = c
        self.embeddings = _Embeddings(c)
        self.encoder = _Encoder(c)
        self.pooler = _Pooler(c)

    def forward(self, ids: torch.Tensor, mask: torch.Tensor, types: torch.Tensor) -> torch.Tensor:
        x = self.embeddings(ids, types)  # (B, L, H)
        # Padding is masked by a large negative bias on its keys, in the activations' dtype.
        bias = (1.0 - mask[:, None, None, :].to(x.dtype)) * torch.finfo(x.dtype).min  # (B, 1, 1, L)
        for layer in self.encoder.layer:
            x = layer(x, bias)
        return x


class _Transformer(nn.Module):
    """The first module of the folder: the tokenizer and the BERT model (``model``, as sentence-transformers
    names it; ``auto_model`` is the same)."""

    def __init__(self, c: BertConfig, tokenizer: Any, max_seq_length: int) -> None:
        super().__init__()
        self.model = BertModel(c)
        self.tokenizer = tokenizer
        self.max_seq_length = max_seq_length

    @property
    def auto_model(self) -> BertModel:
        return self.model


class SentenceBert(nn.Module):
    """BERT token embeddings, mean-pooled over the tokens, optionally L2-normalised: texts → (B, H)."""

    def __init__(self, c: BertConfig, tokenizer: Any, max_seq_length: int, normalize: bool) -> None:
        super().__init__()
        self.add_module("0", _Transformer(c, tokenizer, max_seq_length))
        self.normalize = normalize

    def __getitem__(self, index: int) -> nn.Module:
        return self._modules[str(index)]  # type: ignore[return-value]

    @property
    def transformer(self) -> _Transformer:
        module: _Transformer = self._modules["0"]  # type: ignore[assignment]
        return module

    def get_embedding_dimension(self) -> int:
        return self.transformer.model.config.hidden_size

    def preprocess(self, texts: list[str]) -> dict[str, torch.Tensor]:
        """B texts → ``input_ids``, ``attention_mask``, ``token_type_ids`` (B, L), padded to the longest."""
        encoded = self.transformer.tokenizer.encode_batch([str(t).strip() for t in texts])
        return {"input_ids": torch.tensor([e.ids for e in encoded], dtype=torch.long),
                "attention_mask": torch.tensor([e.attention_mask for e in encoded], dtype=torch.long),
                "token_type_ids": torch.tensor([e.type_ids for e in encoded], dtype=torch.long)}

    def forward(self, features: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        mask = features["attention_mask"]
        tokens = self.transformer.model(features["input_ids"], mask, features["token_type_ids"])  # (B, L, H)
        weights = mask[..., None].to(tokens.dtype)  # (B, L, 1)
        pooled = (tokens * weights).sum(1) / weights.sum(1).clamp(min=1e-9)  # (B, H)
        if self.normalize:
            pooled = F.normalize(pooled, p=2, dim=1)
        return {**features, "token_embeddings": tokens, "sentence_embedding": pooled}

    @torch.inference_mode()
    def encode(self, texts: list[str], batch_size: int = 32, convert_to_numpy: bool = True,
               normalize_embeddings: bool = False, show_progress_bar: bool = False) -> np.ndarray:
        """N texts → (N, H) float32, in batches of texts of similar length (as sentence-transformers does)."""
        del convert_to_numpy, show_progress_bar  # always numpy; never a progress bar
        if not texts:
            return np.zeros((0, self.get_embedding_dimension()), np.float32)
        was_training = self.training
        self.eval()
        device = next(self.parameters()).device
        order = sorted(range(len(texts)), key=lambda i: -len(texts[i]))
        out = np.zeros((len(texts), self.get_embedding_dimension()), np.float32)
        for start in range(0, len(order), batch_size):
            chunk = order[start:start + batch_size]
            features = {k: v.to(device) for k, v in self.preprocess([texts[i] for i in chunk]).items()}
            emb = self(features)["sentence_embedding"].float()
            if normalize_embeddings:
                emb = F.normalize(emb, p=2, dim=1)
            out[chunk] = emb.cpu().numpy()
        self.train(was_training)
        return out


def _modules_of(folder: Path) -> list[str]:
    path = folder / "modules.json"
    if not path.is_file():
        raise UnsupportedFolderError(f"{path}: missing")
    return [str(m.get("type")) for m in json.loads(path.read_text())]


def load(folder: Path | str, device: str = "cpu") -> SentenceBert:
    """The sentence encoder of a sentence-transformers ``folder`` (see the module docstring).

    Raises:
        UnsupportedFolderError: the folder holds another kind of model; load it with sentence-transformers.
        OSError, ValueError: a file is missing or unreadable.
    """
    from safetensors.torch import load_file
    from tokenizers import Tokenizer

    folder = Path(folder)
    modules = _modules_of(folder)
    if modules[:2] != [_TRANSFORMER, _POOLING] or modules[2:] not in ([], [_NORMALIZE]):
        raise UnsupportedFolderError(f"{folder}: modules {modules} (this loader reads Transformer, "
                                     "Pooling[, Normalize])")
    pooling = json.loads((folder / "1_Pooling" / "config.json").read_text())
    if not pooling.get("pooling_mode_mean_tokens") or any(
            v for k, v in pooling.items() if k.startswith("pooling_mode_") and k != "pooling_mode_mean_tokens"):
        raise UnsupportedFolderError(f"{folder / '1_Pooling' / 'config.json'}: pooling other than the mean of tokens")
    raw = json.loads((folder / "config.json").read_text())
    if raw.get("model_type") != "bert" or raw.get("position_embedding_type", "absolute") != "absolute" \
            or raw.get("hidden_act", "gelu") != "gelu":
        raise UnsupportedFolderError(f"{folder / 'config.json'}: not a BERT encoder with absolute positions and GELU")
    config = BertConfig(**{f: raw[f] for f in BertConfig.__dataclass_fields__})
    if not (folder / "model.safetensors").is_file() or not (folder / "tokenizer.json").is_file():
        raise UnsupportedFolderError(f"{folder}: needs model.safetensors and tokenizer.json")
    st_config = json.loads((folder / "sentence_bert_config.json").read_text()) \
        if (folder / "sentence_bert_config.json").is_file() else {}
    max_len = int(min(st_config.get("max_seq_length", 512), config.max_position_embeddings))
    tokenizer = Tokenizer.from_file(str(folder / "tokenizer.json"))
    tokenizer.enable_truncation(max_len)
    tokenizer.enable_padding(pad_id=0, pad_token="[PAD]")
    model = SentenceBert(config, tokenizer, max_len, normalize=modules[2:] == [_NORMALIZE])
    weights = load_file(str(folder / "model.safetensors"))
    prefix = "bert." if any(k.startswith("bert.") for k in weights) else ""
    state = {f"0.model.{k.removeprefix(prefix)}": v.float() for k, v in weights.items()
             if not k.removeprefix(prefix).startswith(("embeddings.position_ids", "embeddings.token_type_ids"))}
    missing, unexpected = model.load_state_dict(state, strict=False, assign=True)
    if missing or unexpected:
        raise UnsupportedFolderError(f"{folder / 'model.safetensors'}: weights that do not fit a BERT encoder "
                                     f"(missing {missing[:3]}, unexpected {unexpected[:3]})")
    return model.to(device).eval()
