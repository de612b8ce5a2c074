"""The observation grid (drqn_jax/env/grid.py; SPEC §4).

Hand-built scenes (``tests/scenes.py``) rasterised: the window's edges, the
cell and the four channels of each pedestrian, the nearest pedestrian winning
a shared cell (also when the nearer one is occluded), the dense map, relative
speed and threat channels; then the cell index, the cell centres and the
replay's record (``GridInputs``) directly.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.grid import (
    GridInputs,
    cell_centres,
    grid_cell_index,
    rasterize,
    rasterize_grid,
)
from drqn_jax.env.params import EnvParams
from tests.helpers import assert_tree_equal
from tests.scenes import FAR_X, LANE_Y, make_ego, make_peds


@pytest.fixture(scope="module")
def raster(static):
    return jax.jit(rasterize_grid, static_argnums=3)


def _grid_scene(params, static, positions, **kw):
    ego = make_ego(params, static, s=20.0)
    return ego, make_peds(static, positions, park_x=FAR_X, **kw)


@pytest.mark.parametrize(
    ("x_rel", "y_rel"),
    [
        (50.0, 0.0),  # far ahead
        (40.0, 0.0),  # row 45: the window is [-5, 40)
        (-10.0, 0.0),  # far behind
        (-6.0, 0.0),  # row -1 (would wrap to row 44)
        (-5.5, 3.0),  # row -1
        (-6.0, -16.0),  # row -1 and col -1
        (10.0, -20.0),  # col -5
        (10.0, -15.5),  # col -1 (would wrap to the previous row's last column)
        (10.0, 15.5),  # col 30 (would spill into the next row's first column)
        (0.0, 15.0),  # col 30 exactly: [-15, 15)
    ],
)
def test_grid_drops_pedestrians_outside_window(params, static, raster, x_rel, y_rel):
    ego, peds = _grid_scene(params, static, [(20.0 + x_rel, LANE_Y + y_rel)])
    grid = np.asarray(raster(ego, peds, params, static))
    assert grid.shape == (45, 30, 4)
    assert not np.any(grid), np.argwhere(grid)
    _, inside = grid_cell_index(peds.position, ego, params, static)
    assert not np.any(np.asarray(inside))


def test_grid_places_pedestrians_in_expected_cells(params, static, raster):
    s = 20.0
    cases = [
        # (x_rel, y_rel, heading, velocity, semantic ch3, row, col)
        (7.3, 2.6, 2.0, (0.3, -0.4), 1.0, 12, 17),  # on the road
        (-4.5, -3.2, -2.5, (0.0, 1.0), 1 / 3, 0, 11),  # right sidewalk, row 0
        (25.0, 1.75, -math.pi / 2, (0.0, -0.2), 2 / 3, 30, 16),  # main crosswalk at x = 45
        (39.5, 14.5, 0.0, (0.0, 0.0), 0.0, 44, 29),  # last cell, off-road
    ]
    positions = [(s + c[0], LANE_Y + c[1]) for c in cases]
    ego, peds = _grid_scene(
        params,
        static,
        positions,
        headings=[c[2] for c in cases],
        velocities=[c[3] for c in cases],
    )
    grid = np.asarray(raster(ego, peds, params, static))
    for x_rel, y_rel, heading, vel, sem, row, col in cases:
        assert row == math.floor(x_rel + 5) and col == math.floor(y_rel + 15)
        wrapped = (heading + math.pi) % (2 * math.pi) - math.pi
        want = [1.0, wrapped / math.pi, math.hypot(*vel) / 2.0, sem]
        np.testing.assert_allclose(grid[row, col], want, rtol=1e-5, atol=1e-6)
    assert int(np.count_nonzero(grid[..., 0])) == len(cases)
    mask = np.zeros(grid.shape[:2], bool)
    for c in cases:
        mask[c[5], c[6]] = True
    assert not np.any(grid[~mask])
    # Heading pi (as atan2 may return) wraps to -pi: channel 1 is -1, in [-1, 1).
    for heading in (math.pi, -math.pi):
        ego, peds = _grid_scene(params, static, [(s + 1.2, LANE_Y)], headings=[heading])
        grid = np.asarray(raster(ego, peds, params, static))
        assert grid[6, 15, 1] == pytest.approx(-1.0, abs=1e-6)


@pytest.mark.parametrize("nearer_first", [True, False])
def test_grid_nearest_pedestrian_wins_shared_cell(params, static, raster, nearer_first):
    s = 20.0
    near = ((s + 10.2, LANE_Y + 0.3), 1.0, (0.2, 0.0))
    far = ((s + 10.8, LANE_Y + 0.9), -2.0, (0.0, 1.0))
    order = [near, far] if nearer_first else [far, near]
    ego, peds = _grid_scene(
        params,
        static,
        [p[0] for p in order],
        headings=[p[1] for p in order],
        velocities=[p[2] for p in order],
    )
    grid = np.asarray(raster(ego, peds, params, static))
    np.testing.assert_allclose(grid[15, 15], [1.0, 1.0 / math.pi, 0.1, 1.0], rtol=1e-5)
    assert int(np.count_nonzero(grid[..., 0])) == 1


@pytest.mark.parametrize("num", [12, 40])
def test_nearest_wins_equals_the_numpy_oracle(num):
    # P pedestrians in 4 cells with many exact distance ties: the OR-ed rows agree
    # with the NumPy oracle's (P, P) mask reduced by ``np.any``, one winner per cell.
    from drqn_jax.env.grid import _nearest_wins
    from tests.env.numpy_env import _nearest_wins as oracle

    rng = np.random.default_rng(num)
    flat = rng.integers(0, 4, (50, num)).astype(np.int32)
    dist2 = rng.integers(0, 3, (50, num)).astype(np.float32)
    got = np.asarray(
        jax.jit(jax.vmap(_nearest_wins, (0, 0, None)), static_argnums=2)(flat, dist2, 1350)
    )
    for row in range(50):
        np.testing.assert_array_equal(got[row], oracle(flat[row], dist2[row], 1350))
        kept = got[row] < 1350
        assert sorted(flat[row][kept]) == sorted(set(flat[row]))


def test_grid_semantic_map_channel(static, raster):
    params = EnvParams(semantic_channel="map")
    ego, peds = _grid_scene(params, static, [(20.0 + 0.5, LANE_Y + 6.5)])  # on the sidewalk
    grid = np.asarray(raster(ego, peds, params, static))
    # Cell centres: x = 15.5 + row, y = -1.75 - 14.5 + col.
    assert grid[5, 15, 3] == pytest.approx(1.0)  # (20.5, -1.75) road
    assert grid[5, 21, 3] == pytest.approx(1 / 3)  # (20.5, 4.75) walkway
    assert grid[5, 29, 3] == 0.0  # (20.5, 12.75) off-road
    assert grid[29, 15, 3] == pytest.approx(2 / 3)  # (44.5, -1.75) crosswalk
    assert grid[34, 29, 3] == pytest.approx(1.0)  # (49.5, 12.75) cross street
    assert int(np.count_nonzero(grid[..., 0])) == 1
    assert grid[5, 21, 0] == 1.0


def test_an_occluded_pedestrian_never_takes_a_visible_ones_cell(params, static, raster):
    """The nearer of two pedestrians in cell (15, 15) is occluded: the farther one
    shows; with both occluded the cell is empty."""
    s = 20.0
    ego, peds = _grid_scene(
        params,
        static,
        [(s + 10.2, LANE_Y + 0.3), (s + 10.8, LANE_Y + 0.9)],
        headings=[1.0, -2.0],
        velocities=[(0.2, 0.0), (0.0, 1.0)],
    )
    visible = np.ones(static.num_pedestrians, bool)
    visible[0] = False
    grid = np.asarray(raster(ego, peds.replace(visible=jnp.asarray(visible)), params, static))
    np.testing.assert_allclose(grid[15, 15], [1.0, -2.0 / math.pi, 0.5, 1.0], rtol=1e-6)
    assert int(np.count_nonzero(grid[..., 0])) == 1
    visible[1] = False
    grid = np.asarray(raster(ego, peds.replace(visible=jnp.asarray(visible)), params, static))
    assert not np.any(grid)


def test_grid_relative_speed_channel(params, static, raster):
    """``speed_channel = "relative"``: |pedestrian velocity - ego velocity| /
    ``speed_norm_relative`` (6 m/s): a pedestrian walking across at 3 m/s in front
    of the ego at 4 m/s closes at 5 m/s."""
    p = params.replace(speed_channel="relative")
    ego = make_ego(p, static, s=20.0, v=4.0)
    peds = make_peds(static, [(21.2, LANE_Y + 0.5)], velocities=[(0.0, 3.0)], park_x=FAR_X)
    grid = np.asarray(raster(ego, peds, p, static))
    assert grid[6, 15, 2] == pytest.approx(5.0 / 6.0, rel=1e-6)
    assert grid[6, 15, 0] == 1.0
    # the pedestrian channel of the same scene: its own speed / 2 m/s
    assert np.asarray(raster(ego, peds, params, static))[6, 15, 2] == pytest.approx(1.5)


def test_grid_threat_channel(params, static, raster):
    """``semantic_channel = "threat"``: 1 - t / ttc_horizon (3 s), t when the pedestrian,
    walking on, is in the corridor (half width 0.9 + 0.3 + 0.5 m) ahead of the bumper
    (x = 22.25, the ego at 4 m/s): in it now 1; 3 m off at 1.5 m/s, t = 2 s: 1/3; the same
    1.75 m ahead of the bumper, passed before it enters, 0; walking away 0; 5.7 m off at
    1.5 m/s, t = 3.8 s beyond the horizon, 0; walking along the lane, t = 1 s, 2/3."""
    p = params.replace(semantic_channel="threat")
    ego = make_ego(p, static, s=20.0, v=4.0)
    positions = [(30.0, LANE_Y + 0.5), (35.0, LANE_Y + 4.7), (24.0, LANE_Y + 4.7)]
    positions += [(30.0, LANE_Y + 5.0), (38.0, LANE_Y - 7.4), (28.0, LANE_Y + 3.2)]
    velocities = [(0.0, 0.0), (0.0, -1.5), (0.0, -1.5), (0.0, 1.0), (0.0, 1.5), (1.0, -1.5)]
    peds = make_peds(static, positions, velocities=velocities, park_x=FAR_X)
    grid = np.asarray(raster(ego, peds, p, static))
    cells = [(15, 15), (20, 19), (9, 19), (15, 20), (23, 7), (13, 18)]
    assert [grid[r, c, 0] for r, c in cells] == [1.0] * 6
    expected = [1.0, 1 / 3, 0.0, 0.0, 0.0, 2 / 3]
    np.testing.assert_allclose([grid[r, c, 3] for r, c in cells], expected, atol=1e-6)
    assert np.asarray(raster(ego, peds, params, static))[15, 15, 3] == 1.0  # class: road
    # a standing ego: every pedestrian ahead in the lane is in its path for good
    grid = np.asarray(raster(make_ego(p, static, s=20.0, v=0.0), peds, p, static))
    assert grid[15, 15, 3] == 1.0 and grid[9, 19, 3] == pytest.approx(1 / 3, abs=1e-6)


def test_grid_cell_index_by_hand(params, static):
    """Ego at s = 20 on the lane centre y = -1.75: row ``floor(x - s + 5)``, column
    ``floor(y + 1.75 + 15)``, flat ``row * 30 + col``; outside the window ``45 * 30``."""
    ego = make_ego(params, static, s=20.0)
    positions = jnp.array(
        [
            [20.5, LANE_Y + 0.5],  # row 5, col 15
            [15.0, -16.75],  # the window's corner: row 0, col 0
            [59.9, 13.15],  # row 44, col 29: the last cell
            [60.0, 0.0],  # row 45: beyond the window
            [14.9, 0.0],  # row -1
            [30.0, 13.25],  # col 30
        ]
    )
    flat, inside = jax.jit(grid_cell_index, static_argnums=3)(positions, ego, params, static)
    np.testing.assert_array_equal(np.asarray(flat), [165, 0, 1349, 1350, 1350, 1350])
    np.testing.assert_array_equal(np.asarray(inside), [True, True, True, False, False, False])


def test_cell_centres_lie_in_their_own_cells(params, static):
    ego = make_ego(params, static, s=20.0)
    centres = np.asarray(cell_centres(ego, params, static))
    assert centres.shape == (45, 30, 2)
    np.testing.assert_allclose(centres[0, 0], [15.5, -16.25])
    np.testing.assert_allclose(centres[44, 29], [59.5, 12.75])
    flat, inside = grid_cell_index(jnp.asarray(centres.reshape(-1, 2)), ego, params, static)
    assert np.all(np.asarray(inside))
    np.testing.assert_array_equal(np.asarray(flat), np.arange(45 * 30))


def test_the_record_rasterises_to_the_same_grid(params, static, raster):
    """``rasterize(GridInputs.of(ego, peds))`` is ``rasterize_grid(ego, peds)``, bit for
    bit, and ``GridInputs.empty`` is shaped as a record of P pedestrians."""
    s = 20.0
    ego, peds = _grid_scene(
        params,
        static,
        [(s + 7.3, LANE_Y + 2.6), (s - 4.5, LANE_Y - 3.2), (s + 10.2, LANE_Y + 0.3)],
        headings=[2.0, -2.5, 1.0],
        velocities=[(0.3, -0.4), (0.0, 1.0), (0.2, 0.0)],
    )
    record = GridInputs.of(ego, peds)
    from_record = jax.jit(rasterize, static_argnums=2)(record, params, static)
    assert_tree_equal(from_record, raster(ego, peds, params, static))
    assert int(np.count_nonzero(np.asarray(from_record)[..., 0])) == 3
    empty = GridInputs.empty(static.num_pedestrians)
    assert jax.tree.map(lambda x: (x.shape, x.dtype), empty) == jax.tree.map(
        lambda x: (x.shape, x.dtype), record
    )
