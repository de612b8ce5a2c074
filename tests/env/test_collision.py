"""Collision and time to collision (drqn_jax/env/collision.py; SPEC §5).

Hand-built scenes (``tests/scenes.py``) driven through the env: the contact
collision, the authors' zone, and TTC of standing and walking pedestrians;
then the geometry (``ego_box``, ``box_squared_distance``, ``box_disc_overlap``),
``collision_test`` and ``classify_hits`` on points placed by hand.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.collision import (
    box_disc_overlap,
    box_squared_distance,
    classify_hits,
    collision_test,
    ego_box,
    squared_length,
    time_to_collision,
)
from drqn_jax.env.params import COLLISION_CONTACT, TTC_COLLISION
from drqn_jax.env.state import ACCELERATE, STEER
from tests import scenes
from tests.scenes import LANE_Y, first_index, make_ego, make_peds, make_state


@pytest.fixture(scope="module")
def run_scene(env):
    return functools.partial(scenes.run_scene, env)


@pytest.fixture(scope="module")
def ttc_fn(static):
    return jax.jit(time_to_collision, static_argnums=3)


# --- driving into a standing pedestrian ------------------------------------------


def test_accelerating_into_standing_pedestrian_collides(env, params, static, run_scene):
    """``collision_model = "contact"``: the collision is the step the box meets the disc."""
    params = params.replace(collision_model="contact")
    s0 = float(params.ego_start_s)
    ped_xy = (s0 + 8.0, LANE_Y)
    state = make_state(make_ego(params, static, s=s0), make_peds(static, [ped_xy]))
    _, out = run_scene(state, params, action=ACCELERATE)

    hit = first_index(out["collision"])
    assert out["terminated"][hit]
    assert out["reward"][hit] == pytest.approx(params.reward_collision)
    assert not np.any(out["collision"][:hit]) and not np.any(out["terminated"][:hit])
    # Bounds from the plant: gap to cover from the front bumper to the disc.
    gap = 8.0 - 0.5 * params.ego_length - params.ped_radius  # 5.45 m
    a_max = params.throttle_max * params.accel_throttle
    a_sat = a_max - params.rolling_resistance
    t_hit = (hit + 1) * params.dt
    assert t_hit <= math.sqrt(2 * gap / a_sat) + params.accel_lag + 2 * params.dt  # 24 steps
    assert t_hit >= math.sqrt(2 * gap / a_max)  # ~1.9 s even without the lag
    # At the collision step the box truly overlaps the disc; one step earlier it did not.
    front = out["s"] + 0.5 * params.ego_length
    assert front[hit] > ped_xy[0] - params.ped_radius
    assert front[hit - 1] <= ped_xy[0] - params.ped_radius
    # The pedestrian never moved (it is standing; overlap came from the ego).
    np.testing.assert_array_equal(
        out["ped_position"][: hit + 1, 0], np.broadcast_to(np.float32(ped_xy), (hit + 1, 2))
    )
    # The ego only ever accelerated.
    assert np.all(out["action"] == ACCELERATE)


@pytest.mark.parametrize(
    ("y", "contact", "authors"), [(LANE_Y, True, True), (-3.3, False, True), (1.75, False, False)]
)
def test_authors_zone_is_the_ego_lane_around_the_car(
    params, static, run_scene, y, contact, authors
):
    """``collision_model = "authors"`` (carla-gym ``is_collision``): a pedestrian on
    the ego's lane within -2.2..+3.5 m of its centre is hit, touching or not; one in
    the other lane is not. Driving at a standing pedestrian, the authors' test fires
    when the pedestrian is 3.5 m ahead of the ego's centre, 1.25 m before the
    bumper meets the disc."""
    hits = {}
    for model in ("contact", "authors"):
        p = params.replace(collision_model=model)
        state = make_state(make_ego(p, static, s=5.0, v=15 / 3.6), make_peds(static, [(20.0, y)]))
        _, out = run_scene(state, p, action=STEER)
        hits[model] = np.flatnonzero(out["collision"])
    assert (hits["contact"].size > 0) == contact and (hits["authors"].size > 0) == authors
    if contact and authors:
        assert hits["authors"][0] < hits["contact"][0]


# --- time to collision ------------------------------------------------------------


def _expected_ttc(v: float, d: float, params) -> float:
    """First k*0.1 s at which the front bumper strictly passes the disc's near edge."""
    gap = d - 0.5 * params.ego_length - params.ped_radius
    if gap < 0:
        return 0.0
    q = gap / (v * 0.1)
    assert abs(q - round(q)) > 0.05, "test case on a sampling boundary"
    return float(np.float32(math.floor(q) + 1) * np.float32(0.1))


@pytest.mark.parametrize(
    ("v", "d", "want"),
    [
        (4.0, 10.0, 1.9),  # gap 7.45 m -> 1.8625 s
        (2.5, 6.0, 1.4),  # gap 3.45 m -> 1.38 s
        (5.0, 8.0, 1.1),  # gap 5.45 m -> 1.09 s
        (2.0, 8.45, 3.0),  # gap 5.90 m -> 2.95 s: the horizon sample counts
        (1.0, 2.5, 0.0),  # already overlapping (gap -0.05 m)
    ],
)
def test_ttc_standing_pedestrian_ahead(params, static, ttc_fn, v, d, want):
    s = 20.0
    ego = make_ego(params, static, s=s, v=v)
    peds = make_peds(static, [(s + d, LANE_Y)], park_x=s + 60.0)
    ttc = float(ttc_fn(ego, peds, params, static))
    assert _expected_ttc(v, d, params) == pytest.approx(want, abs=1e-6)
    assert ttc == pytest.approx(want, abs=1e-6)


@pytest.mark.parametrize(
    ("v", "d", "y"),
    [
        (0.0, 4.0, LANE_Y),  # stopped
        (0.05, 2.5, LANE_Y),  # below stopped_speed, even when overlapping
        (2.0, 10.2, LANE_Y),  # gap 7.35 m: 3.675 s, beyond the 3 s horizon
        (4.0, 6.0, 1.75),  # standing in the other lane: never in the path
        (4.0, -6.0, LANE_Y),  # behind the ego
    ],
)
def test_ttc_infinite(params, static, ttc_fn, v, d, y):
    s = 20.0
    ego = make_ego(params, static, s=s, v=v)
    peds = make_peds(static, [(s + d, y)], park_x=s + 60.0)
    assert math.isinf(float(ttc_fn(ego, peds, params, static)))


def test_ttc_moving_pedestrian_and_minimum(params, static, ttc_fn):
    s, v = 20.0, 4.0
    ego = make_ego(params, static, s=s, v=v)
    # Walking from the left lane (y = 1.25) towards the ego's lane at 1 m/s:
    # at t = 1.8 s dx = 0.55 m (apart), at t = 1.9 s dx = 0.15, dy = 0.2,
    # distance 0.25 < 0.3 (overlap) -> TTC 1.9.
    crossing = (s + 10.0, 1.25)
    peds = make_peds(static, [crossing], velocities=[(0.0, -1.0)], speeds=[1.0], park_x=s + 60.0)
    assert float(ttc_fn(ego, peds, params, static)) == pytest.approx(1.9, abs=1e-6)
    # The same pedestrian standing still is never in the path.
    still = make_peds(static, [crossing], park_x=s + 60.0)
    assert math.isinf(float(ttc_fn(ego, still, params, static)))
    # Minimum over pedestrians: add one standing at 6.0 m (gap 3.45 m -> 0.9 s).
    both = make_peds(
        static,
        [crossing, (s + 6.0, LANE_Y)],
        velocities=[(0.0, -1.0), (0.0, 0.0)],
        park_x=s + 60.0,
    )
    assert float(ttc_fn(ego, both, params, static)) == pytest.approx(0.9, abs=1e-6)


def test_ttc_of_the_collision_test(params, static, ttc_fn):
    """``reward_ttc_test = "collision"`` projects the collision test: under the authors'
    model its zone (3.5 m ahead of the centre, the whole lane across), so a pedestrian at
    the lane's edge, which the footprint never meets, has a TTC, and a crossing one an
    earlier one; under the contact model it is the footprint's TTC."""
    s, v = 20.0, 4.0
    ego = make_ego(params, static, s=s, v=v)
    zone = params.replace(reward_ttc_test=TTC_COLLISION)
    # Standing at the lane's edge 10 m ahead: in the zone once 10 - 4t <= 3.5, t >= 1.625.
    edge = make_peds(static, [(s + 10.0, -0.2)], park_x=s + 60.0)
    assert math.isinf(float(ttc_fn(ego, edge, params, static)))
    assert float(ttc_fn(ego, edge, zone, static)) == pytest.approx(1.7, abs=1e-6)
    # Crossing from the left lane at 1 m/s: in the lane from t = 1.25 s, in reach from
    # t = 1.625 s; the footprint meets it at 1.9 s.
    crossing = make_peds(
        static, [(s + 10.0, 1.25)], velocities=[(0.0, -1.0)], speeds=[1.0], park_x=s + 60.0
    )
    assert float(ttc_fn(ego, crossing, zone, static)) == pytest.approx(1.7, abs=1e-6)
    contact = zone.replace(collision_model=COLLISION_CONTACT)
    assert float(ttc_fn(ego, crossing, contact, static)) == pytest.approx(1.9, abs=1e-6)


# --- the geometry and the tests, by hand --------------------------------------------


def test_squared_length_and_box_squared_distance():
    """Squared distances from the box centred at (1, -1) with half extents (2, 1):
    0 inside and on the edge, the gap to the nearest edge (or corner) outside."""
    assert float(squared_length(jnp.array([3.0, -4.0]))) == 25.0
    np.testing.assert_array_equal(squared_length(jnp.zeros((2, 3, 2))), np.zeros((2, 3)))
    centre, half = jnp.array([1.0, -1.0]), jnp.array([2.0, 1.0])
    points = jnp.array(
        [
            [1.0, -1.0],  # the centre
            [3.0, 0.0],  # a corner
            [2.5, -1.5],  # inside
            [4.0, -1.0],  # 1 m right of the right edge
            [1.0, -4.0],  # 2 m below the bottom edge
            [6.0, 4.0],  # 3 m right and 4 m above the top right corner
            [-3.0, -1.0],  # 2 m left of the left edge
        ]
    )
    got = box_squared_distance(centre, half, points)
    np.testing.assert_array_equal(np.asarray(got), [0.0, 0.0, 0.0, 1.0, 4.0, 25.0, 4.0])
    # a batch of boxes against one point broadcasts
    centres = jnp.array([[1.0, -1.0], [10.0, -1.0]])
    np.testing.assert_array_equal(box_squared_distance(centres, half, points[3]), [1.0, 16.0])


def test_box_disc_overlap_is_strict():
    """A disc of radius 1 whose centre is 1 m from the box only touches it: no overlap."""
    centre, half = jnp.zeros(2), jnp.array([2.0, 1.0])
    discs = jnp.array([[3.0, 0.0], [2.5, 0.0], [0.0, 2.0], [0.0, 1.99], [2.7, 1.7], [2.8, 1.8]])
    got = np.asarray(box_disc_overlap(centre, half, discs, 1.0))
    # corner distances: (0.7, 0.7) -> 0.99 apart (overlap), (0.8, 0.8) -> 1.13 (none)
    np.testing.assert_array_equal(got, [False, True, False, True, True, False])


def test_ego_box_is_the_footprint_on_the_lane_centre(params):
    centre, half = ego_box(jnp.array([5.0, 20.0, 37.5]), params)
    np.testing.assert_array_equal(
        np.asarray(centre), [[5.0, LANE_Y], [20.0, LANE_Y], [37.5, LANE_Y]]
    )
    np.testing.assert_allclose(np.asarray(half), [2.25, 0.9], rtol=1e-6)
    _, inflated = ego_box(jnp.float32(5.0), params, inflate=0.2)
    np.testing.assert_allclose(np.asarray(inflated), [2.45, 1.1], rtol=1e-6)


# Pedestrians (x - s, y) and whether the contact test and the authors' test hit them,
# with the ego at s = 20: the box is x in [17.75, 22.25], y in [-2.65, -0.85]; the
# authors' zone x in [17.8, 23.5] (2.2 m behind, 3.5 m ahead), y in [-3.5, 0] (the
# ego's lane: |y - LANE_Y| <= 2.2 cut to the lane). The disc's radius is 0.3 m.
HITS = [
    (2.25 + 0.25, LANE_Y, True, True),  # centre 0.25 m ahead of the front bumper
    (2.25 + 0.35, LANE_Y, False, True),  # 0.35 m ahead: clear of the box, in the zone
    (3.4, -1.0, False, True),  # in the zone's front
    (3.6, -1.0, False, False),  # beyond it
    (-2.1, LANE_Y, True, True),  # inside the box, in the zone's back
    (-2.3, LANE_Y, True, False),  # 5 cm behind the rear bumper: behind the zone
    (-2.6, LANE_Y, False, False),  # 0.35 m behind it
    (0.0, -0.85 + 0.25, True, True),  # 5 cm into the disc, beside the box's left side
    (0.0, 0.1, False, False),  # over the centre line: the other lane
    (0.0, -3.4, False, True),  # the lane's right edge
]


@pytest.mark.parametrize("model", ["contact", "authors"])
def test_collision_test_of_each_model_by_hand(params, static, model):
    s = 20.0
    p = params.replace(collision_model=model)
    ego = make_ego(p, static, s=s, v=4.0)
    peds = make_peds(static, [(s + dx, y) for dx, y, *_ in HITS], park_x=s + 60.0)
    got = np.asarray(jax.jit(collision_test)(ego, peds, p))
    want = [contact if model == "contact" else authors for *_, contact, authors in HITS]
    np.testing.assert_array_equal(got[: len(HITS)], want)


@pytest.mark.parametrize(
    ("v", "hit", "want"),
    [
        (4.0, True, (True, False)),  # moving: the ego's collision
        (0.1, True, (True, False)),  # at stopped_speed it counts as moving
        (0.05, True, (False, True)),  # standing: struck while stopped
        (0.0, True, (False, True)),
        (4.0, False, (False, False)),
        (0.0, False, (False, False)),
    ],
)
def test_classify_hits_by_the_egos_speed(params, static, v, hit, want):
    s = 20.0
    p = params.replace(collision_model="contact")
    x = s + (2.4 if hit else 4.0)  # the disc reaches 2.1 m ahead of the centre, or 3.7 m
    ego = make_ego(p, static, s=s, v=v)
    peds = make_peds(static, [(x, LANE_Y)], park_x=s + 60.0)
    collision, struck = jax.jit(classify_hits)(ego, peds, p)
    assert (bool(collision), bool(struck)) == want
