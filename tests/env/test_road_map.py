"""The map (drqn_jax/env/road_map.py; SPEC §1): lane centre, intersections and
crosswalks, and the semantic class of points placed by hand."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.road_map import (
    CROSSING_AREA,
    ROAD,
    crosswalk_centres,
    intersection_centres,
    lane_centre_y,
    semantic_class,
)
from tests.scenes import LANE_Y


def test_lane_centre(params):
    assert float(lane_centre_y(params)) == LANE_Y


def test_intersections_and_crosswalks_of_the_paper_world(params, static):
    """Cross streets at x = 50, 100, 150 m (7 m wide), a 3 m crosswalk across the main
    road either side of each: centres 5 m from the street's."""
    np.testing.assert_array_equal(np.asarray(intersection_centres(params, static)), [50, 100, 150])
    crosswalks = np.asarray(crosswalk_centres(params, static))
    np.testing.assert_array_equal(crosswalks, [45, 95, 145, 55, 105, 155])
    on_road = jnp.stack([jnp.asarray(crosswalks), jnp.zeros(6)], axis=-1)
    assert np.all(np.asarray(semantic_class(on_road, params, static)) == CROSSING_AREA)
    centres = jnp.stack([intersection_centres(params, static), jnp.zeros(3)], axis=-1)
    assert np.all(np.asarray(semantic_class(centres, params, static)) == ROAD)


@pytest.mark.parametrize(
    ("x", "y", "cls"),
    [
        (20.0, LANE_Y, 3),  # road
        (20.0, 5.0, 1),  # main sidewalk
        (20.0, -5.0, 1),  # main sidewalk, right
        (45.0, 0.0, 2),  # main crosswalk [43.5, 46.5]
        (55.0, LANE_Y, 2),  # main crosswalk after the intersection [53.5, 56.5]
        (50.0, 5.0, 2),  # crosswalk across the cross street
        (50.0, 0.0, 3),  # the intersection box
        (20.0, 10.0, 0),  # off-road / building
        (45.0, 10.0, 1),  # cross-street sidewalk
        (100.0, 20.0, 3),  # second cross street, far from the main road
        (154.0, 0.0, 2),  # third intersection's far crosswalk
        (57.5, -1.0, 3),  # road past the crosswalk
    ],
)
def test_semantic_map_spot_checks(params, static, x, y, cls):
    got = semantic_class(jnp.array([x, y], jnp.float32), params, static)
    assert got.shape == ()
    assert int(got) == cls


def test_semantic_map_batched_shape(params, static):
    xy = jnp.array([[[20.0, LANE_Y], [20.0, 5.0]], [[45.0, 0.0], [20.0, 10.0]]], jnp.float32)
    got = np.asarray(semantic_class(xy, params, static))
    assert got.shape == (2, 2)
    np.testing.assert_array_equal(got, [[3, 1], [2, 0]])
