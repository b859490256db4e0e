"""Time slots: sentences' steps stretched over K slots on the text side, frames pooled into them on the video side."""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from captioning.text import caption_halves
from encoders.config import ConfigError, DualEncoderConfig, FusionConfig, TextConfig, tiny_model_config
from encoders.fusion import ViewFusion
from encoders.model import DualEncoder
from encoders.sentence import TextModelUnavailableError
from encoders.text import SlotText, sentence_steps, text_sentences
from encoders.timeline import SlotReadout, SlotTextHead, slot_of_steps
from encoders.train_config import HardNegative
from tests.encoders.synthetic import SyntheticClipDataset, SyntheticSpec, collate_clips

os.environ["HF_HUB_OFFLINE"] = "1"
CAPTION = "The ego vehicle is cruising straight. A car in the left lane approaches, then moves away."
REVERSED = "The ego vehicle is cruising straight. A car in the left lane moves away, then approaches."


def test_sentences_keep_their_own_steps() -> None:
    assert sentence_steps(CAPTION) == [["The ego vehicle is cruising straight"],
                                       ["A car in the left lane approaches", "then moves away"]]
    assert sentence_steps("we brake and stop") == [["we brake and stop"]]
    assert sentence_steps("A stops. B turns. C waits, then goes.") == [["A stops"], ["B turns"],
                                                                      ["C waits", "then goes"]]
    assert sentence_steps("it brakes, after that it turns") == [["it brakes", "it turns"]]
    assert sentence_steps("") == [[""]] and sentence_steps("...") == [["..."]] and sentence_steps(". a.") == [["a"]]


def test_a_captions_sentences_are_its_halves_as_written() -> None:
    assert text_sentences(CAPTION) == list(caption_halves(CAPTION))
    assert text_sentences(CAPTION) == ["The ego vehicle is cruising straight.",
                                       "A car in the left lane approaches, then moves away."]
    assert text_sentences(" we brake and stop ") == ["we brake and stop"]  # one sentence: the text itself
    assert text_sentences("A car cuts in!  Then it stops?") == ["A car cuts in!", "Then it stops?"]
    assert text_sentences("") == [""] and text_sentences("...") == ["..."] and text_sentences(". a.") == ["a."]


def test_steps_share_the_slots_evenly() -> None:
    assert slot_of_steps(1, 4) == [0, 0, 0, 0]
    assert slot_of_steps(2, 4) == [0, 0, 1, 1]
    assert slot_of_steps(3, 4) == [0, 0, 1, 2]
    assert slot_of_steps(6, 4) == [0, 1, 3, 4]  # more steps than slots: some steps go unseen in the slots


def test_one_head_for_every_slot_so_reversed_steps_are_reversed_slots() -> None:
    torch.manual_seed(0)
    head = SlotTextHead(features=8, embed_dim=20, slots=4, slot_dim=3, hidden=16)
    whole, a, b = torch.randn(3, 8)
    def features(first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
        return torch.cat([whole, first, first, second, second])[None]  # (1, 8 + 4·8)
    x, x_rev = head(features(a, b)), head(features(b, a))  # (1, 20) each
    assert x.shape == (1, 20)
    torch.testing.assert_close(x[:, :8], x_rev[:, :8])  # the global part reads the whole text only
    slots, slots_rev = x[0, 8:].reshape(4, 3), x_rev[0, 8:].reshape(4, 3)
    torch.testing.assert_close(slots, slots_rev.flip(0))
    assert not torch.allclose(slots, slots_rev)


def test_readout_slots_start_at_the_clips_ends_and_evenly_between() -> None:
    """The first slot starts on the first frame and the last on the last: where a caption's first and last
    steps hold, whatever the steps' durations."""
    torch.manual_seed(0)
    readout = SlotReadout(width=6, embed_dim=14, slots=3, slot_dim=2)
    torch.nn.init.zeros_(readout.score.weight)
    torch.nn.init.zeros_(readout.score.bias)
    tokens = torch.randn(2, 13, 6)  # (B, T, W)
    weights = readout.attention(tokens).detach()  # (B, K, T)
    torch.testing.assert_close(weights.sum(-1), torch.ones(2, 3))
    assert weights[0].argmax(-1).tolist() == [0, 6, 12]  # centres 0, 1/2, 1 of frames 0..12
    # A first step of one frame: the first slot sees it (its weight there is its largest).
    assert float(weights[0, 0, 0]) > 0.3 > 0.01 > float(weights[0, 1, 0])
    out = readout(tokens.mean(1), tokens)
    assert out.shape == (2, 14)
    out_rev = readout(tokens.mean(1), tokens.flip(1))
    torch.testing.assert_close(out[:, 8:].reshape(2, 3, 2), out_rev[:, 8:].reshape(2, 3, 2).flip(1))
    assert readout(tokens[:, :1].mean(1), tokens[:, :1]).shape == (2, 14)  # a one-frame clip


def test_fusion_mlp_leaves_the_slots_as_the_views_mixed_them() -> None:
    torch.manual_seed(0)
    fusion = ViewFusion(FusionConfig(hidden=16), dim=20, slot_dims=12).eval()
    camera, bev = torch.randn(3, 20), torch.randn(3, 20)
    has_camera = torch.tensor([True, False, True])
    out = fusion(camera, bev, has_camera)
    mixed = torch.where(has_camera[:, None], (F.normalize(camera, dim=-1) + F.normalize(bev, dim=-1)) / 2,
                        F.normalize(bev, dim=-1))
    torch.testing.assert_close(out[:, 8:], mixed[:, 8:])
    assert not torch.allclose(out[:, :8], mixed[:, :8])


def test_time_slots_and_the_slots_text_go_together() -> None:
    with pytest.raises(ConfigError, match="go together"):
        DualEncoderConfig(time_slots=4)
    with pytest.raises(ConfigError, match="go together"):
        DualEncoderConfig(text=TextConfig(kind="slots"))
    with pytest.raises(ConfigError, match="global dimensions"):
        DualEncoderConfig(embed_dim=64, time_slots=4, slot_dim=16, text=TextConfig(kind="slots"))


@pytest.fixture(scope="module")
def model() -> DualEncoder:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    tiny = tiny_model_config()
    config = DualEncoderConfig(**{**tiny.__dict__, "embed_dim": 32, "time_slots": 4, "slot_dim": 4,
                                  "text": TextConfig(kind="slots", step_hidden=16)})
    try:
        return DualEncoder(config).eval()
    except TextModelUnavailableError as exc:
        pytest.skip(f"the pretrained sentence encoder is not installed: {exc}")


def test_text_slots_hold_each_sentences_steps_in_order(model: DualEncoder) -> None:
    backbone = model.text.backbone
    assert isinstance(backbone, SlotText) and backbone.out_features == 384 * (1 + 4)
    assert model.text.frozen_prefixes() == ["backbone.sentence.encoder."]
    cache = backbone.cache
    assert cache is not None
    with torch.no_grad():
        x = backbone([CAPTION, REVERSED], torch.device("cpu")).reshape(2, 5, 384)
    steps = ("The ego vehicle is cruising straight", "A car in the left lane approaches", "then moves away")
    host, first, then = (torch.from_numpy(cache.get(s)) for s in steps)
    # The whole text: the mean of its sentences, each encoded alone; the caption itself is not encoded.
    sentences = [torch.from_numpy(cache.get(s)) for s in caption_halves(CAPTION)]
    torch.testing.assert_close(x[0, 0], (sentences[0] + sentences[1]) / 2)
    assert cache.get(CAPTION) is None
    # Slot k at 1 + k: the host sentence in every slot, the object's two steps over two slots each, averaged.
    for k, step in enumerate([first, first, then, then]):
        torch.testing.assert_close(x[0, 1 + k], (host + step) / 2)
    one = backbone(["we brake and stop"], torch.device("cpu")).reshape(5, 384)
    assert torch.equal(one[1], one[4]) and torch.equal(one[0], one[1])  # one sentence, one step: every slot


def test_the_whole_text_in_one_piece_as_runs_before_the_sentences(model: DualEncoder) -> None:
    config = dataclasses.replace(model.config.text, whole_text="text")
    backbone = SlotText(config, time_slots=4)
    with torch.no_grad():
        x = backbone([CAPTION], torch.device("cpu")).reshape(5, 384)
    assert backbone.cache is not None
    torch.testing.assert_close(x[0], torch.from_numpy(backbone.cache.get(CAPTION)))


@pytest.mark.parametrize("view", ["fused", "camera", "bev"])
def test_slotted_model_keeps_its_shapes_and_reads_frame_order(model: DualEncoder, view: str) -> None:
    ds = SyntheticClipDataset(2, spec=SyntheticSpec(frames=8, camera_hw=(32, 48), bev_hw=(32, 16),
                                                    camera_fraction=1.0), seed=3)
    batch = collate_clips([ds[i] for i in range(2)])
    flipped = {k: v.flip(1) if isinstance(v, torch.Tensor) and v.ndim >= 3 else v for k, v in batch.items()}
    with torch.no_grad():
        text = model.encode_text([CAPTION, REVERSED, "a cyclist next to us on the right"])
        video, video_flipped = model.encode_video(batch, view), model.encode_video(flipped, view)
    assert text.shape == (3, 32) and video.shape == (2, 32)
    torch.testing.assert_close(text.norm(dim=-1), torch.ones(3))
    assert not torch.allclose(video, video_flipped, atol=1e-4)


def test_recipes_set_the_slots_on_both_sides(tmp_path: Path) -> None:
    from retrieval.commands import train as train_command

    parser = argparse.ArgumentParser()
    train_command.configure(parser)
    base = ["clips", "--out", str(tmp_path / "run")]
    config = train_command.build_recipe(parser.parse_args(base)).train
    assert config.model.time_slots == 4 and config.model.text.kind == "slots"
    assert config.hard_negatives == (HardNegative.REVERSE,)
    off = train_command.build_recipe(parser.parse_args([*base, "--set", "model.time_slots=0", "--set",
                                                        "model.text.kind=pretrained"])).train
    assert off.model.time_slots == 0 and off.model.text.kind == "pretrained"
    with pytest.raises(ConfigError, match="time_slots > 0 and model.text.kind: slots go together"):
        train_command.build_recipe(parser.parse_args([*base, "--set", "model.time_slots=0"]))
    with pytest.raises(ConfigError, match="global dimensions"):  # the tiny model's 32 dimensions hold no slots
        train_command.build_recipe(parser.parse_args([*base, "--preset", "tiny", "--set", "model.time_slots=4",
                                                      "--set", "model.text.kind=slots"]))
