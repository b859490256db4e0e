"""Tag tensors, region pooling and compositions on a hand-made E and A, checked exactly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from encoders.tagging.attributes import Region, TagError
from encoders.tagging.head import TagHead, TagHeadConfig
from encoders.tagging.scene_tags import (
    compose,
    ego_region_mask,
    parse_tag_expression,
    pool,
    pool_values,
    region_mask,
    region_masks,
    sigmoid,
    tag_tensor,
    values_of,
)
from scenes.bev import BevGrid

# A 4 × 2 grid of 10 m cells: rows centred on x = 25, 15, 5, −5 m; columns on y = 5, −5 m.
GRID = BevGrid(x_min_m=-10.0, x_max_m=30.0, y_min_m=-10.0, y_max_m=10.0, resolution_m=10.0)


def hand_made() -> tuple[np.ndarray, np.ndarray]:
    """E (T=2, D=2, H=4, W=2) and A (3, 2)."""
    e = np.zeros((2, 2, 4, 2), np.float32)
    e[0, 0] = [[1, 2], [3, 4], [5, 6], [7, 8]]
    e[0, 1] = [[0, 1], [0, 1], [0, 1], [0, 1]]
    e[1, 0] = -e[0, 0]
    e[1, 1] = 2.0
    a = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, -1.0]], np.float32)
    return e, a


def test_tag_tensor_is_the_dot_product_over_channels() -> None:
    e, a = hand_made()
    v = tag_tensor(e, a, 2)
    assert v.shape == (2, 4, 2)
    expected0 = 0.5 * np.array([[1, 2], [3, 4], [5, 6], [7, 8]]) - np.array([[0, 1]] * 4)
    np.testing.assert_array_equal(v[0], expected0)
    np.testing.assert_array_equal(v[1], -0.5 * np.array([[1, 2], [3, 4], [5, 6], [7, 8]]) - 2.0)


def test_head_equals_tag_tensor_plus_bias_times_scale() -> None:
    e, a = hand_made()
    head = TagHead(TagHeadConfig(attributes=("parked", "vehicle_speed", "stopped"), embed_channels=2))
    with torch.no_grad():
        head.attributes.copy_(torch.from_numpy(a))
        head.bias.copy_(torch.tensor([0.0, 1.0, -1.0]))
    v = head(torch.from_numpy(e)[None])[0].detach().numpy()  # (T, 3, H, W)
    np.testing.assert_allclose(v[:, 0], tag_tensor(e, a, 0), atol=1e-6)
    np.testing.assert_allclose(v[:, 1], 10.0 * (tag_tensor(e, a, 1) + 1.0), atol=1e-5)  # speed in m/s
    np.testing.assert_allclose(v[:, 2], tag_tensor(e, a, 2) - 1.0, atol=1e-6)


def test_ego_regions_in_metres() -> None:
    # Cell centres: x = 25, 15, 5, −5 (rows); y = 5, −5 (columns).
    np.testing.assert_array_equal(ego_region_mask(GRID, Region.FRONT), [[1, 1], [1, 1], [1, 1], [0, 0]])
    np.testing.assert_array_equal(ego_region_mask(GRID, Region.BEHIND), [[0, 0], [0, 0], [0, 0], [1, 1]])
    # around: within 15 m of the ego: (5, ±5) and (−5, ±5) (7.1 m), not (15, ±5) (15.8 m).
    np.testing.assert_array_equal(ego_region_mask(GRID, Region.AROUND), [[0, 0], [0, 0], [1, 1], [1, 1]])
    assert ego_region_mask(GRID, Region.FULL).all()


def test_pooling_sums_densities_and_maxes_probabilities_exactly() -> None:
    e, a = hand_made()
    v = tag_tensor(e, a, 0)  # (2, 4, 2): frame 0 = 1..8, frame 1 = −1..−8
    front = ego_region_mask(GRID, Region.FRONT)
    dens = pool(v, front, "vehicle_density", cell_area_m2=100.0)
    np.testing.assert_allclose(dens, [100.0 * (1 + 2 + 3 + 4 + 5 + 6), -100.0 * 21])
    prob = pool(v, front, "parked")
    np.testing.assert_allclose(prob, sigmoid(np.array([6.0, -1.0])), rtol=1e-6)
    speed = pool(v, ego_region_mask(GRID, Region.BEHIND), "vehicle_speed")
    np.testing.assert_allclose(speed, [8.0, -7.0])
    # Empty region → 0 for max.
    np.testing.assert_array_equal(pool_values(v, np.zeros((4, 2), bool), "max"), [0.0, 0.0])


def test_a_density_learned_as_presence_sums_its_confident_cells_times_the_footprint() -> None:
    logits = np.log(np.array([[0.9, 0.2], [0.5, 0.49], [0.7, 0.1], [0.95, 0.0001]]) /
                    (1 - np.array([[0.9, 0.2], [0.5, 0.49], [0.7, 0.1], [0.95, 0.0001]])))
    front = ego_region_mask(GRID, Region.FRONT)  # the first three rows
    got = pool(logits.astype(np.float32), front, "pedestrian_density", cell_area_m2=100.0, footprint_m2=0.36)
    # Cells below p = 0.5 count nothing (else a region's many small p add up to absent pedestrians).
    assert float(got) == pytest.approx(0.36 * (0.9 + 0.5 + 0.7), rel=1e-5)
    share = values_of(logits.astype(np.float32), "pedestrian_density", footprint_share=0.0036)
    assert share[0, 1] == 0.0 and share[0, 0] == pytest.approx(0.9 * 0.0036, rel=1e-5)
    # Regressed (no footprint): V itself is the covered fraction.
    np.testing.assert_allclose(values_of(logits, "pedestrian_density"), logits, rtol=1e-6)


def test_map_regions_follow_the_map_layers_and_fail_without_a_map() -> None:
    layers = np.zeros((3, 6, 4, 2), np.float32)  # (F, Cm, H, W)
    layers[1, 5, 0, 1] = 1.0  # intersection at frame 1
    layers[:, 4, 3, 0] = 1.0  # crossing everywhere
    masks = region_masks(GRID, layers)
    assert masks[Region.INTERSECTION].shape == (3, 4, 2) and masks[Region.INTERSECTION].sum() == 1
    assert masks[Region.CROSSWALK][:, 3, 0].all()
    no_map = region_masks(GRID, None)
    assert region_mask(no_map, "front").shape == (4, 2)
    with pytest.raises(TagError, match="needs the log's map"):
        region_mask(no_map, "intersection")
    with pytest.raises(TagError, match="valid regions: full, front, behind, around, intersection, crosswalk"):
        region_mask(masks, "left")


def test_compose_and_or_identity_and_indicator_exactly() -> None:
    p = np.array([[0.2, 0.9], [0.6, 0.0]], np.float32)
    q = np.array([[0.5, 0.5], [1.0, 0.3]], np.float32)
    np.testing.assert_allclose(compose([p, q], "and"), p * q)
    np.testing.assert_allclose(compose([p, q], "or"), p + q - p * q)
    np.testing.assert_array_equal(compose([p, q], "and", "indicator", 0.5), [[0, 1], [1, 0]])
    np.testing.assert_array_equal(compose([p, q], "or", "indicator", 0.5), [[1, 1], [1, 0]])
    r = np.full((2, 2), 0.5, np.float32)
    np.testing.assert_allclose(compose([p, q, r], "or"), 1 - (1 - p) * (1 - q) * (1 - r), rtol=1e-6)
    # Composition, then pooling over a region: the best cell of the product.
    mask = np.array([[1, 1], [0, 0]], bool)
    assert pool_values(compose([p, q], "and"), mask, "max") == pytest.approx(0.45)


def test_parse_tag_expressions_and_their_errors() -> None:
    e = parse_tag_expression("blocked_by & four_way")
    assert e.attributes == ("blocked_by", "four_way") and e.op == "and" and str(e) == "blocked_by & four_way"
    assert parse_tag_expression("stopped or braking").op == "or"
    assert parse_tag_expression("parked").attributes == ("parked",)
    with pytest.raises(TagError, match="twice"):
        parse_tag_expression("stopped & stopped")
    with pytest.raises(TagError, match="valid attributes: vehicle_density, pedestrian_density"):
        parse_tag_expression("stopped & flying")
    with pytest.raises(TagError, match="mixes"):
        parse_tag_expression("stopped & braking | parked")
    with pytest.raises(TagError, match="empty"):
        parse_tag_expression("  ")


def test_l1_calibration_fits_scale_and_offset_and_falls_back_to_a_constant() -> None:
    from encoders.tagging.evaluate import calibrate_l1

    rng = np.random.default_rng(0)
    truth = rng.uniform(0.0, 4.0, 200).astype(np.float32)
    scale, offset = calibrate_l1(2.0 * truth + 3.0, truth)  # biased and stretched predictions
    assert scale == 0.5 and offset == pytest.approx(-1.5, abs=1e-5)
    scale, offset = calibrate_l1(rng.uniform(0, 1, 200).astype(np.float32), truth)  # noise → the median
    assert scale == 0.0 and offset == pytest.approx(float(np.median(truth)))


def test_thresholds_fall_back_to_always_present_and_to_training_logs() -> None:
    from encoders.tagging.evaluate import SplitPooled, best_threshold, metrics_by_region

    truth = np.array([1, 1, 1, 1, 0], bool)  # present in most frames
    useless = np.array([0.2, 0.05, 0.9, 0.1, 0.95], np.float32)  # scores that do not separate them
    assert best_threshold(useless, truth) == pytest.approx(0.05)  # every frame, as a real threshold
    assert best_threshold(useless, truth, allow_always=True) == 0.0  # F1 8/9: answering "always"
    separating = np.array([0.9, 0.8, 0.7, 0.6, 0.1], np.float32)
    assert best_threshold(separating, truth, allow_always=True) == pytest.approx(0.35)  # midway in the gap

    def split(t: list[float], p: list[float]) -> SplitPooled:
        return SplitPooled({"stopped": {"front": np.array(t, np.float32)}},
                           {"stopped": {"front": np.array(p, np.float32)}})

    test = split([1, 0, 1, 0], [0.3, 0.1, 0.35, 0.05])
    no_positives = split([0, 0], [0.1, 0.2])
    train = split([1, 0, 0, 1], [0.3, 0.1, 0.2, 0.4])
    cell = metrics_by_region(test, no_positives, train)["stopped"]["front"]
    assert cell["threshold_from"] == "train" and cell["threshold"] == pytest.approx(0.25) and cell["value"] == 1.0
    cell = metrics_by_region(test, no_positives)["stopped"]["front"]
    assert cell["threshold_from"] == "default" and cell["value"] == 0.0  # 0.5 finds nothing


def test_f1_is_undefined_where_no_test_frame_is_positive() -> None:
    from encoders.tagging.evaluate import SplitPooled, markdown_tables, metrics_by_region, skill, table2_row

    test = SplitPooled({"stopped": {"front": np.array([0, 0, 0], np.float32), "full": np.array([1, 0, 1], np.float32)}},
                       {"stopped": {"front": np.array([0.9, 0.1, 0.2], np.float32),
                                    "full": np.array([0.9, 0.1, 0.8], np.float32)}})
    val = SplitPooled({"stopped": {"front": np.array([1, 0], np.float32), "full": np.array([1, 0], np.float32)}},
                      {"stopped": {"front": np.array([0.9, 0.1], np.float32),
                                   "full": np.array([0.9, 0.1], np.float32)}})
    by_region = metrics_by_region(test, val)
    assert by_region["stopped"]["front"]["value"] is None  # no positive frame: F1 undefined, not 0
    assert by_region["stopped"]["full"]["value"] == 1.0
    row = table2_row(by_region)
    assert row["stopped"]["value"] == 1.0  # the mean leaves the undefined region out
    assert skill(row, {}) == 1.0
    assert "n/a" in markdown_tables(by_region, {"both": row}, {"both": 1.0})
    only_undefined = table2_row({"stopped": {"front": by_region["stopped"]["front"]}})
    assert only_undefined["stopped"]["value"] is None and np.isnan(skill(only_undefined, {}))


def test_thresholds_split_scores_whatever_their_scale() -> None:
    """Squashed but well-ranked probabilities (all within 0.20–0.24) still get the separating
    threshold: the candidates come from the scores, not from a fixed grid."""
    from encoders.tagging.evaluate import best_threshold, f1_score

    rng = np.random.default_rng(0)
    truth = rng.random(400) < 0.2  # (N,) a rare tag
    prob = np.where(truth, 0.23, 0.21) + rng.uniform(-0.009, 0.009, 400)  # (N,) ranked, squashed
    threshold = best_threshold(prob, truth, allow_always=True)
    assert 0.21 < threshold < 0.23
    assert f1_score(prob >= threshold, truth) == 1.0
    # Ties in the scores are one candidate, not several.
    assert best_threshold(np.array([0.3, 0.3, 0.1]), np.array([True, False, False])) == pytest.approx(0.2)
