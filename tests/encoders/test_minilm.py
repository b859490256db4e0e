"""The plain-torch BERT sentence encoder gives sentence-transformers' embeddings and shares its weights' names."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from encoders import minilm
from encoders.config import BUNDLED_TEXT_MODEL
from encoders.sentence import resolve_text_model

TEXTS = ["A car in the left lane approaches, then moves into the host lane.", "stopped car", "",
         "  The ego vehicle is cruising straight.  ", "pedestrian " * 400]


@pytest.fixture(scope="module")
def folder() -> Path:
    return Path(resolve_text_model(BUNDLED_TEXT_MODEL))


def test_embeddings_and_state_dict_match_sentence_transformers(folder: Path) -> None:
    from sentence_transformers import SentenceTransformer

    light = minilm.load(folder)
    reference = SentenceTransformer(str(folder), device="cpu")
    xb = reference.encode(TEXTS, normalize_embeddings=True, convert_to_numpy=True)
    xq = light.encode(TEXTS, normalize_embeddings=True)
    assert xq.shape == (len(TEXTS), 384)
    assert float((xq * xb).sum(axis=1).min()) > 0.99999
    features = light.preprocess(TEXTS[:3])
    for name, value in reference.preprocess(TEXTS[:3]).items():
        if name in features:
            assert torch.equal(features[name], value), name
    assert light.state_dict().keys() == reference.state_dict().keys()  # a run's weights load into either
    assert light[0].auto_model.encoder.layer[5] is light.transformer.model.encoder.layer[5]  # type: ignore[index]


def test_the_bundled_encoder_loads_without_sentence_transformers() -> None:
    code = ("import sys; from encoders.sentence import shared_sentence_encoder; "
            "m = shared_sentence_encoder(); m.encode(['a car']); "
            "print(type(m).__name__, 'sentence_transformers' in sys.modules, 'transformers' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2]).stdout.split()
    assert out == ["SentenceBert", "False", "False"]


@pytest.mark.parametrize("change", ["cls_pooling", "other_module", "not_bert"])
def test_a_folder_of_another_shape_is_left_to_sentence_transformers(folder: Path, tmp_path: Path, change: str
                                                                    ) -> None:
    copy = tmp_path / "model"
    shutil.copytree(folder, copy)
    if change == "cls_pooling":
        path = copy / "1_Pooling" / "config.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), "pooling_mode_cls_token": True}))
    elif change == "other_module":
        path = copy / "modules.json"
        modules = json.loads(path.read_text())
        path.write_text(json.dumps([*modules[:2], {"idx": 2, "name": "2", "path": "2_Dense",
                                                   "type": "sentence_transformers.models.Dense"}]))
    else:
        path = copy / "config.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), "model_type": "roberta"}))
    with pytest.raises(minilm.UnsupportedFolderError):
        minilm.load(copy)


def test_training_mode_drops_out_and_eval_mode_is_deterministic(folder: Path) -> None:
    model = minilm.load(folder)
    features = model.preprocess(TEXTS[:2])
    first = model(features)["sentence_embedding"]
    assert torch.equal(first, model(features)["sentence_embedding"])
    model.train()
    torch.manual_seed(0)
    assert not torch.allclose(first, model(features)["sentence_embedding"])
    model.eval()
    assert np.allclose(model.encode(TEXTS[:2], normalize_embeddings=True),
                       torch.nn.functional.normalize(first, dim=1).detach().numpy(), atol=1e-6)


def test_a_few_texts_run_in_float32_and_a_batch_in_the_inference_dtype() -> None:
    import contextlib

    from encoders.sentence import FEW_TEXTS, few_texts, inference_autocast

    with few_texts(1):
        assert isinstance(inference_autocast("cpu", torch.bfloat16), contextlib.nullcontext)
    with few_texts(FEW_TEXTS):
        assert isinstance(inference_autocast("cpu", torch.bfloat16), torch.autocast)
    assert isinstance(inference_autocast("cpu", torch.bfloat16), torch.autocast)  # outside: as before
