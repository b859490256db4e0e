"""The model card says what the run trained: the ego and track inputs, the slots and the dense heads."""

from __future__ import annotations

import dataclasses

import pytest

from encoders.calibration import CameraWeightChoice
from encoders.config import BevConfig, CameraConfig, DualEncoderConfig, TextConfig
from encoders.model_card import model_card
from encoders.train_config import HardNegative, TrainConfig


def _card(config: TrainConfig) -> str:
    return model_card(config, [{"epoch": 1, "val": {"R@5": 0.5}}], 10, None, "clips/",
                      CameraWeightChoice(0.0, {0.0: 0.7, 1.0: 0.6}))


def test_card_names_the_track_inputs_the_time_slots_and_the_dense_heads() -> None:
    model = DualEncoderConfig(time_slots=4, slot_dim=48, text=TextConfig(kind="slots"), dense_streams=("track",),
                              bev=BevConfig(track_velocity=True))
    card = _card(TrainConfig(model=model, dense_weight=1.0, hard_negatives=(HardNegative.REVERSE,)))
    assert ("the object's own track (11 features per frame + velocity relative to the ego and own speed, "
            "acceleration and yaw rate)") in card
    assert "pools its frame tokens into 4 stretches of the clip, in order (48 dims each)" in card
    assert "per-frame rule tags (lane, motion, host_motion, host_direction, action, context) on the track " \
           "stream's frame tokens, weight 1" in card
    assert "hard negatives (edited steps): reverse" in card
    assert "temporal transformer with ego motion (x_m, y_m, yaw_rad, speed_mps, accel_mps2, yaw_rate_rps)" in card
    plain = _card(TrainConfig(model=dataclasses.replace(model, time_slots=0, text=TextConfig(), dense_streams=(),
                                                        bev=BevConfig(track_features=0))))
    assert "own track" not in plain and "time slots" not in plain and "per-frame" not in plain
    assert "hard negatives (edited steps): none." in plain
    older = _card(TrainConfig(model=dataclasses.replace(model, bev=BevConfig(ego_features=4))))
    assert "temporal transformer with ego motion (x_m, y_m, yaw_rad, speed_mps);" in older
    assert "temporal transformer over frames." in plain


def test_card_names_what_the_camera_reads_besides_its_pixels() -> None:
    camera = CameraConfig(ego_features=6, mask_scale=True)
    card = _card(TrainConfig(model=DualEncoderConfig(camera=camera)))
    assert ("temporal transformer over frames that also reads the ego motion (x_m, y_m, yaw_rad, speed_mps, "
            "accel_mps2, yaw_rate_rps) and the object's size on a log scale.") in card
    ego_only = _card(TrainConfig(model=DualEncoderConfig(camera=CameraConfig(ego_features=6))))
    assert "log scale" not in ego_only and "over frames that also reads the ego motion (x_m," in ego_only
    assert "trained apart" not in card
    apart = _card(TrainConfig(model=DualEncoderConfig(camera=camera), camera_apart=True))
    assert "- The camera tower trained apart: its own view loss" in apart


def test_card_says_in_which_precision_the_frozen_text_encoder_ran(monkeypatch: pytest.MonkeyPatch) -> None:
    import encoders.sentence as sentence

    monkeypatch.setattr(sentence, "native_bfloat16", lambda: True)
    assert "(frozen, cached; precision auto: bfloat16 on the machine that trained it)" in _card(TrainConfig())
    monkeypatch.setattr(sentence, "native_bfloat16", lambda: False)
    assert "precision auto: float32" in _card(TrainConfig())
    forced = TrainConfig(model=DualEncoderConfig(text=TextConfig(precision="bfloat16")))
    assert "precision bfloat16: bfloat16" in _card(forced)
    tuned = TrainConfig(model=DualEncoderConfig(text=TextConfig(finetune_top_layers=2)))
    assert "(frozen below its top 2 layers, float32)" in _card(tuned)


def test_an_evaluation_section_is_added_once_and_replaced_when_evaluated_again() -> None:
    from encoders.model_card import with_section

    card = _card(TrainConfig())
    first = with_section(card, "Evaluation: split test of `clips`", "| figure | model |\n| R@5 | 0.123 |")
    assert first.startswith(card.rstrip("\n")) and first.count("## Evaluation: split test of `clips`") == 1
    other = with_section(first, "Evaluation: split all of `real`", "| R@5 | 0.7 |")
    again = with_section(other, "Evaluation: split test of `clips`", "| figure | model |\n| R@5 | 0.9 |")
    assert again.count("## Evaluation") == 2 and "0.123" not in again and "| R@5 | 0.9 |" in again
    assert again.index("split test") < again.index("split all") and "| R@5 | 0.7 |" in again
    assert again.endswith("\n") and "## Limits" in again
