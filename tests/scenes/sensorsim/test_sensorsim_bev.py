"""BEV rasters: boxes, map layers and LiDAR occupancy, with the image convention checked."""

from __future__ import annotations

import numpy as np
import pytest

from scenes.bev import (
    MAP_LAYERS,
    BevGrid,
    MapRasterizer,
    count_points,
    rasterize_boxes,
    rasterize_map,
)
from scenes.geometry import SE3
from scenes.sensorsim.synthetic import crossroad_map

GRID = BevGrid()  # x −20..60, y −20..20, 0.5 m: 160 rows × 80 columns


def _cells(raster: np.ndarray) -> set[tuple[int, int]]:
    return {(int(r), int(c)) for r, c in np.argwhere(raster > 0)}


def test_grid_convention() -> None:
    assert GRID.shape == (160, 80)
    centers = GRID.cell_centers_xy()
    assert np.allclose(centers[0, 0], [59.75, 19.75])  # row 0 ahead, column 0 left
    assert np.allclose(centers[-1, -1], [-19.75, -19.75])
    px = GRID.ego_to_pixel(np.array([[59.75, 19.75], [0.0, 0.0]]))
    assert np.allclose(px[0], [0, 0]) and np.allclose(px[1], [39.5, 119.5])


def test_axis_aligned_box_covers_exactly_its_cells() -> None:
    raster = rasterize_boxes(GRID, np.array([[10.0, 5.0]]), np.array([[4.0, 2.0]]), np.array([0.0]))
    # x in [8, 12] → rows (60 − 12)/0.5 = 96 … 99; y in [4, 6] → columns (20 − 6)/0.5 = 28 … 31.
    expected = {(r, c) for r in range(96, 104) for c in range(28, 32)}
    assert _cells(raster) == expected
    assert raster.dtype == np.float32 and raster.max() == 1.0


def test_rotated_box_matches_the_centre_test() -> None:
    center, size, yaw = np.array([20.0, -6.0]), np.array([6.0, 2.4]), 0.6
    raster = rasterize_boxes(GRID, center[None], size[None], np.array([yaw]))
    xy = GRID.cell_centers_xy() - center
    c, s = np.cos(yaw), np.sin(yaw)
    lx, ly = c * xy[..., 0] + s * xy[..., 1], -s * xy[..., 0] + c * xy[..., 1]
    inside = (np.abs(lx) <= size[0] / 2) & (np.abs(ly) <= size[1] / 2)
    assert np.array_equal(raster > 0, inside)
    turned = rasterize_boxes(GRID, center[None], size[None], np.array([yaw + np.pi / 2]))
    assert abs(int((turned > 0).sum()) - int(inside.sum())) <= 0.1 * inside.sum()


def test_values_and_overlap_order() -> None:
    centers = np.array([[0.0, 0.0], [1.0, 0.0]])
    sizes = np.array([[4.0, 2.0], [4.0, 2.0]])
    raster = rasterize_boxes(GRID, centers, sizes, np.zeros(2), values=np.array([3.0, 7.0]))
    row_of = lambda x: int((GRID.x_max_m - x) / GRID.resolution_m)  # noqa: E731
    col0 = int((GRID.y_max_m - 0.25) / GRID.resolution_m)
    assert raster[row_of(-1.75), col0] == 3.0  # only the first box
    assert raster[row_of(0.25), col0] == 7.0  # overlap: the later box wins
    assert raster[row_of(2.75), col0] == 7.0


def test_coverage_is_fractional_and_conserves_area() -> None:
    # A box whose edges fall on cell centres covers its border cells by half.
    raster = rasterize_boxes(GRID, np.array([[10.25, 0.0]]), np.array([[2.0, 2.0]]), np.zeros(1), coverage=True)
    assert set(np.unique(raster)) <= {0.0, 0.5, 1.0}
    assert (raster == 0.5).sum() == 8 and (raster == 1.0).sum() == 12
    rotated = rasterize_boxes(GRID, np.array([[15.3, -4.1]]), np.array([[4.6, 1.9]]), np.array([0.77]),
                              coverage=True, supersample=8)
    area = rotated.sum() * GRID.resolution_m**2
    assert area == pytest.approx(4.6 * 1.9, rel=0.03)
    assert rotated.max() == 1.0 and 0 < rotated[rotated > 0].min() < 1


def test_map_layers_around_the_ego() -> None:
    vmap = crossroad_map()
    pose = SE3.from_yaw(0.0, np.array([60.0, -1.75, 0.0]))  # eastbound lane, junction 40 m ahead
    layers = rasterize_map(GRID, vmap, pose)
    assert tuple(layers) == MAP_LAYERS
    at = lambda name, x, y: layers[name][int((GRID.x_max_m - x) / 0.5), int((GRID.y_max_m - y) / 0.5)]  # noqa: E731
    assert at("drivable_area", 0.0, 0.0) == 1.0
    assert at("drivable_area", 0.0, 12.0) == 0.0  # beside the road (its left edge is 8.75 m away)
    assert at("lane_direction_cos", 0.0, 0.0) == pytest.approx(1.0, abs=1e-3)  # own lane: ahead
    assert at("lane_direction_cos", 0.0, 5.0) == pytest.approx(-1.0, abs=1e-3)  # oncoming lane
    assert at("intersections", 40.0, 0.0) == 1.0 and at("intersections", 0.0, 0.0) == 0.0
    assert at("crosswalks", 40.0 - 7.0 - 2.5, 1.75) == 1.0  # the crossing before the junction
    assert at("drivable_area", 40.0, 15.0) == 1.0  # the side road
    assert layers["lane_boundaries"].sum() > 100
    # Turn the ego to face north: the eastbound lane now runs to the ego's right (heading −π/2).
    turned = MapRasterizer(vmap).rasterize(GRID, SE3.from_yaw(np.pi / 2, np.array([60.0, -1.75, 0.0])))
    r, c = int((GRID.x_max_m - 0.0) / 0.5), int((GRID.y_max_m - 0.0) / 0.5)
    assert turned["lane_direction_sin"][r, c] == pytest.approx(-1.0, abs=1e-3)


def test_count_points_counts_points_in_their_cells_and_drops_the_rest() -> None:
    points = np.array([[10.1, 5.1, 0.5], [10.2, 5.2, 0.6], [10.1, 5.1, 2.5], [-30.0, 0.0, 0.5], [0.0, 0.0, 9.0]])
    counts = count_points(GRID, np.array([0.0, 1.0, 3.0]), [(points.T.astype(np.float32), np.eye(4))])
    assert counts.shape == (2, 160, 80)
    r, c = int((60.0 - 10.1) / 0.5), int((20.0 - 5.1) / 0.5)
    assert counts[0, r, c] == 2 and counts[1, r, c] == 1
    assert counts.sum() == 3  # the point behind the grid and the one above the bins are dropped
    for edges in ([1.0, 0.0], [0.0], np.arange(256.0), [1.0, 1.0 + 1e-9]):  # the last two equal as float32
        with pytest.raises(ValueError, match="increasing"):
            count_points(GRID, np.array(edges), [])


def test_count_points_keeps_the_grid_and_bins_half_open_and_drops_points_that_are_not_finite() -> None:
    # Edges: x = x_max and y = y_max are the first row and column, x = x_min and y = y_min lie outside;
    # z = the lowest edge is in the first bin, z = the highest is outside.
    points = np.array([[60.0, 0.1, 0.5], [-20.0, 0.1, 0.5], [0.1, 20.0, 0.5], [0.1, -20.0, 0.5],
                       [0.1, 0.1, 0.0], [0.1, 0.1, 3.0], [np.nan, 0.1, 0.5], [np.inf, 0.1, 0.5],
                       [0.1, -np.inf, 0.5], [0.1, 0.1, np.nan]])
    counts = count_points(GRID, np.array([0.0, 1.0, 3.0]), [(points.T.astype(np.float32), np.eye(4))])
    assert counts[0, 0, int((20.0 - 0.1) / 0.5)] == 1
    assert counts[0, int((60.0 - 0.1) / 0.5), 0] == 1
    assert counts[0, int((60.0 - 0.1) / 0.5), int((20.0 - 0.1) / 0.5)] == 1
    assert counts.sum() == 3


def test_count_points_moves_each_cloud_by_its_pose_and_counts_it_in_its_cell() -> None:
    rng = np.random.default_rng(0)
    edges = np.array([-0.5, 0.3, 1.0, 2.0, 4.0])
    expected = np.zeros((4, *GRID.shape), np.int64)
    clouds = []
    for _ in range(3):  # a frame's sweep and two earlier ones, each with its own pose
        ego_SE3_cloud = SE3.from_yaw(rng.uniform(-np.pi, np.pi), rng.uniform(-5, 5, 3)).matrix
        n = 2000
        rows, cols, bins = rng.integers(0, 160, n), rng.integers(0, 80, n), rng.integers(0, 4, n)
        # Inside their cell and height bin, away from every edge: float32 rounding cannot move them.
        x = GRID.x_max_m - (rows + rng.uniform(0.05, 0.95, n)) * GRID.resolution_m
        y = GRID.y_max_m - (cols + rng.uniform(0.05, 0.95, n)) * GRID.resolution_m
        z = edges[bins] + rng.uniform(0.05, 0.95, n) * np.diff(edges)[bins]
        np.add.at(expected, (bins, rows, cols), 1)
        outside = np.array([[-30.0, 0.0, 0.5], [70.0, 0.0, 0.5], [0.0, 25.0, 0.5], [0.0, -25.0, 0.5],
                            [0.0, 0.0, -0.6], [0.0, 0.0, 4.0], [1e7, -1e7, 1e7], [-1e7, 1e7, -1e7]])
        ego = np.concatenate([np.stack([x, y, z], axis=1), outside])
        cloud = (ego - ego_SE3_cloud[:3, 3]) @ ego_SE3_cloud[:3, :3]  # into the cloud's own frame
        clouds.append((np.ascontiguousarray(cloud.T, dtype=np.float32), ego_SE3_cloud))
    counts = count_points(GRID, edges, clouds)
    assert counts.dtype == np.int64 and counts.shape == (4, 160, 80)
    np.testing.assert_array_equal(counts, expected)
    assert count_points(GRID, edges, []).sum() == 0
