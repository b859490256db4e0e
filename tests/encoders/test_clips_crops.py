"""Object-centred crops: the box lands in the middle of the crop with its context, small objects are
magnified at most twice, the mask and the colours follow the object, and the box columns say where it was."""

from __future__ import annotations

import numpy as np
import pytest

from encoders.clips.crops import (
    CROP_CONTEXT,
    CROP_MIN_HALF_HEIGHT_PX,
    ObjectCrops,
    crop_affine,
    crop_instances,
    crop_projected,
)

HC, WC = 32, 64


def _apply(affine: np.ndarray, xy: tuple[float, float]) -> np.ndarray:
    return affine[:, :2] @ np.asarray(xy, dtype=np.float64) + affine[:, 2]


def test_the_box_centre_is_the_crop_centre_and_the_box_fills_it_with_context() -> None:
    box = (100.0, 50.0, 180.0, 90.0)  # 80 × 40 pixels: the camera's aspect
    affine = crop_affine(box, HC, WC)
    np.testing.assert_allclose(_apply(affine, (140.0, 70.0)), (WC / 2, HC / 2))
    # Its height spans 1 / CROP_CONTEXT of the crop's.
    top, bottom = _apply(affine, (140.0, 50.0))[1], _apply(affine, (140.0, 90.0))[1]
    assert bottom - top == pytest.approx(HC / CROP_CONTEXT)


def test_a_tall_box_sets_the_height_and_a_tiny_one_is_magnified_at_most_to_the_minimum_crop() -> None:
    tall = crop_affine((10.0, 10.0, 20.0, 70.0), HC, WC)  # 10 × 60: the height decides
    assert tall[1, 1] * 60.0 == pytest.approx(HC / CROP_CONTEXT)
    tiny = crop_affine((300.0, 200.0, 304.0, 203.0), HC, WC)  # 4 × 3 pixels
    assert tiny[0, 0] == pytest.approx(HC / (2 * CROP_MIN_HALF_HEIGHT_PX))


def _scene() -> tuple[np.ndarray, np.ndarray]:
    """A 360 × 640 BGR image with a red 6 × 6 object (track 0) and a blue 60 × 30 one (track 1)."""
    bgr = np.full((360, 640, 3), 90, np.uint8)
    labels = np.zeros((360, 640), np.uint16)
    bgr[200:206, 400:406] = (0, 0, 255)
    labels[200:206, 400:406] = 1
    bgr[100:130, 50:110] = (255, 0, 0)
    labels[100:130, 50:110] = 2
    return bgr, labels


def test_instance_crops_show_each_object_in_the_middle_in_its_own_colours() -> None:
    bgr, labels = _scene()
    crops = ObjectCrops(frames=3, tracks=3, height_px=HC, width_px=WC)
    labels[300:310, 600:610] = 7  # a value beyond the log's tracks: neither counted nor cropped
    pixels = crop_instances(crops, 1, bgr, labels, np.arange(8, dtype=np.uint16))  # value v: track v − 1
    np.testing.assert_array_equal(pixels, np.bincount(labels.ravel(), minlength=8)[1:4])
    rgb, mask, index, box = crops.arrays()
    assert rgb.shape == (2, HC, WC, 3) and mask.shape == (2, HC, WC) and index.shape == (3, 3)
    assert (index[[0, 2]] == -1).all() and index[1, 2] == -1  # other frames; the track never seen
    for track, colour_rgb, area_px in ((0, (255, 0, 0), 36), (1, (0, 0, 255), 1800)):
        row = index[1, track]
        ys, xs = np.nonzero(mask[row])
        assert abs(ys.mean() - (HC - 1) / 2) < 1.5 and abs(xs.mean() - (WC - 1) / 2) < 1.5
        # Bilinear magnification and area shrinking blend the edge pixels a little.
        np.testing.assert_allclose(rgb[row][mask[row] > 0].mean(axis=0), colour_rgb, atol=20)
        assert set(np.unique(mask[row])) == {0, 1}
        # Where it was in the full image and how many pixels it covered there.
        x0, y0, x1, y1 = ((400, 200, 406, 206) if track == 0 else (50, 100, 110, 130))
        np.testing.assert_allclose(box[1, track], ((x0 + x1) / 640 - 1, (y0 + y1) / 360 - 1,
                                                   np.log1p(area_px) / np.log1p(640 * 360)), rtol=1e-6)
    # The 6-pixel-wide object at least doubles (the minimum crop is 16 pixels high); the large one shrinks.
    assert (mask[index[1, 0]] > 0).sum() >= 4 * 36 * 0.8
    assert (mask[index[1, 1]] > 0).sum() < 1800


def test_stored_mask_values_read_through_a_table_crop_as_the_remapped_mask() -> None:
    bgr, labels = _scene()
    stored = np.zeros_like(labels)  # the file's values: 3 = track 0, 1 = track 1, 2 = no track of the log
    stored[labels == 1], stored[labels == 2] = 3, 1
    stored[300:310, 600:610] = 2
    track_of_value = np.array([0, 2, 0, 1], np.uint16)
    by_table, remapped = (ObjectCrops(frames=1, tracks=3, height_px=HC, width_px=WC) for _ in range(2))
    pixels = crop_instances(by_table, 0, bgr, stored, track_of_value)
    np.testing.assert_array_equal(pixels, crop_instances(remapped, 0, bgr, np.take(track_of_value, stored),
                                                         np.arange(4, dtype=np.uint16)))
    np.testing.assert_array_equal(pixels, [36, 1800, 0])
    for a, b in zip(by_table.arrays(), remapped.arrays(), strict=True):
        np.testing.assert_array_equal(a, b)


def test_projected_crops_mask_the_box_hull_and_skip_hidden_tracks() -> None:
    bgr, _ = _scene()
    corners = np.zeros((2, 8, 2))
    corners[0] = [[50, 100], [110, 100], [110, 130], [50, 130]] * 2  # the blue object's outline
    corners[1] = [[400, 200], [406, 200], [406, 206], [400, 206]] * 2
    crops = ObjectCrops(frames=1, tracks=2, height_px=HC, width_px=WC)
    crop_projected(crops, 0, bgr, corners, np.array([0, 1]), np.array([1800, 0]))  # track 1 hidden
    rgb, mask, index, _ = crops.arrays()
    assert index.tolist() == [[0, -1]]
    np.testing.assert_allclose(rgb[0][mask[0] > 0].mean(axis=0), (0, 0, 255), atol=20)


def test_no_crops_give_empty_arrays_of_the_crop_size() -> None:
    rgb, mask, index, box = ObjectCrops(frames=4, tracks=0, height_px=HC, width_px=WC).arrays()
    assert rgb.shape == (0, HC, WC, 3) and mask.shape == (0, HC, WC)
    assert index.shape == (4, 0) and box.shape == (4, 0, 3)
