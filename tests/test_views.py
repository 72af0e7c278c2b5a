"""Information gains of views against hand calculations, and cooperative choice."""

from __future__ import annotations

import numpy as np
import pytest

from taskcam.mapping import GainModel, OccupancyGrid, Pinhole, SensorModel, View, region_mask

ONE_RAY = Pinhole(1, 1, 1.0, 1.0, 0.0, 0.0)  # a single ray along the optical axis


def along_x(x: float, y: float = 0.05, z: float = 0.05) -> View:
    """A camera at (x, y, z) looking along +x (OpenCV frame: z forward)."""
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    T[:3, 3] = [x, y, z]
    return View(T)


def corridor_grid() -> OccupancyGrid:
    g = OccupancyGrid.from_bounds(np.zeros(3), np.array([2.0, 0.1, 0.1]), 0.1, SensorModel())
    return g  # 20 voxels in a row, all unknown


def model(g: OccupancyGrid, camera: Pinhole = ONE_RAY) -> GainModel:
    return GainModel(g, camera, np.ones(g.shape, dtype=bool), max_range=5.0, stride=1)


def test_entropy_gain_of_unknown_voxels_is_a_geometric_series():
    """Each unknown voxel: 1 bit, seen with probability 0.5^k after k unknown ones; the
    ray stops once that falls below 1e-3 (after 10 voxels)."""
    g = corridor_grid()
    gain = model(g).gains([along_x(0.05)])[0]
    assert gain == pytest.approx(sum(0.5 ** k for k in range(10)), rel=1e-5)


def test_entropy_gain_stops_at_an_occupied_voxel():
    g = corridor_grid()
    free = np.zeros(g.shape, dtype=bool)
    free[:3] = True
    g.set_probability(0.01, free)
    wall = np.zeros(g.shape, dtype=bool)
    wall[3] = True
    g.set_probability(0.9999, wall)
    h = g.entropy().reshape(-1)
    expected = (h[0] + h[1] * 0.99 + h[2] * 0.99 ** 2 + h[3] * 0.99 ** 3
                + sum(1.0 * 0.99 ** 3 * 1e-4 * 0.5 ** k for k in range(0)))
    gain = model(g).gains([along_x(0.05)])[0]
    assert gain == pytest.approx(expected + 0.99 ** 3 * (1 - 0.9999) * 1.0, rel=1e-3)


def test_unobserved_and_rear_side_counts():
    g = corridor_grid()
    seen = np.zeros(g.shape, dtype=bool)
    seen[:4] = True
    g.set_probability(0.1, seen)  # four observed free voxels, then unknown
    m = model(g)
    assert m.gains([along_x(0.05)], "unobserved")[0] == 16  # to the end of the grid
    assert m.gains([along_x(0.05)], "rear_side")[0] == 0  # no surface met
    wall = np.zeros(g.shape, dtype=bool)
    wall[6] = True
    g.set_probability(0.9, wall)  # voxels 4, 5 unknown, 6 occupied, 7.. unknown
    m = model(g)
    assert m.gains([along_x(0.05)], "unobserved")[0] == 2
    assert m.gains([along_x(0.05)], "rear_side")[0] == 1


def test_only_the_region_of_interest_counts():
    g = corridor_grid()
    interest = region_mask(g, np.array([1.55, 0.05, 0.05]), np.array([0.5, 0.5, 0.5]))
    assert interest.sum() == 10
    m = GainModel(g, ONE_RAY, interest, max_range=5.0, stride=1)
    assert m.gains([along_x(0.05)])[0] == pytest.approx(0.0, abs=1e-3)  # attenuated first
    assert m.gains([along_x(1.05)])[0] > 1.9


def test_a_view_expected_to_be_taken_gains_little_more():
    """Cooperative choice: free space, then an unknown layer, then a wall. Once a view
    of the layer is chosen, the same view is worth little and a view of another part of
    the layer keeps its worth; what remains of a voxel is 1 - its visibility."""
    g = OccupancyGrid.from_bounds(np.zeros(3), np.array([1.0, 2.0, 0.5]), 0.1, SensorModel())
    x = g.centers()[..., 0]
    g.set_probability(0.001)
    g.set_probability(0.5, (x > 0.6) & (x < 0.7))  # the unknown layer
    g.set_probability(0.999, x > 0.7)  # the wall
    cam = Pinhole.from_fovy(np.radians(20), 8, 8)
    m = GainModel(g, cam, np.ones(g.shape, dtype=bool), max_range=5.0, stride=1)
    here, elsewhere = along_x(0.05, 0.45, 0.25), along_x(0.05, 1.55, 0.25)
    before = m.gains([here, elsewhere])
    vis = m.footprint(here)
    m.expect(here)
    after = m.gains([here, elsewhere])
    assert after[0] < 0.05 * before[0]
    assert after[1] == pytest.approx(before[1])
    layer = ((x > 0.6) & (x < 0.7)).reshape(-1) & (vis > 0)
    assert layer.sum() > 0 and np.all(vis[layer] > 0.99)  # the layer is in plain view
    assert np.allclose(m.unseen, 1 - vis)


def test_prior_for_unknown_and_known_empty_voxels_on_the_way():
    """With a prior occupancy q for never-observed voxels, the geometric series has ratio
    1 - q; voxels below ``free_below`` let the ray through untouched."""
    g = corridor_grid()
    m = GainModel(g, ONE_RAY, np.ones(g.shape, dtype=bool), max_range=5.0, stride=1,
                  unknown_occupancy=0.05)
    assert m.gains([along_x(0.05)])[0] == pytest.approx(sum(0.95 ** k for k in range(20)),
                                                         rel=1e-6)
    free = np.zeros(g.shape, dtype=bool)
    free[:10] = True
    g.set_probability(0.04, free)
    h = g.entropy().reshape(-1)
    seen_through = GainModel(g, ONE_RAY, np.ones(g.shape, dtype=bool), max_range=5.0,
                             stride=1, unknown_occupancy=0.05, free_below=0.05)
    expected = h[0] * 10 + sum(0.95 ** k for k in range(10))
    assert seen_through.gains([along_x(0.05)])[0] == pytest.approx(expected, rel=1e-4)
    attenuated = GainModel(g, ONE_RAY, np.ones(g.shape, dtype=bool), max_range=5.0,
                           stride=1, unknown_occupancy=0.05)
    assert attenuated.gains([along_x(0.05)])[0] < expected
