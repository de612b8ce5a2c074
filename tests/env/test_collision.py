"""Hand-built scenes: collision, TTC, rule-based stop, pedestrians vs car, grid, map (SPEC §1–6).

Every scene is a full ``EnvState`` with the default P pedestrians: the ones a
test is about come first, the rest stand still on the far (left) sidewalk
ahead of the ego, where they are never despawned, never done and never in
the ego's corridor. Closed-loop scenes run one jitted ``lax.scan`` of
``env.step_env`` (one compile for the module) whose action is either a
fixed action or the rule-based agent's.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_action, rule_based_labels
from drqn_jax.env.collision import box_disc_overlap, ego_box, time_to_collision
from drqn_jax.env.ego import initial_ego
from drqn_jax.env.grid import GridInputs, grid_cell_index, rasterize_grid
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.road_map import lane_centre_y, semantic_class
from drqn_jax.env.state import (
    ACCELERATE,
    BRAKE,
    CROSSING,
    NUM_WAYPOINTS,
    STEER,
    EgoState,
    EnvState,
    PedestrianState,
)

SCAN_STEPS = 200  # one fixed length: one compile serves every closed-loop scene
LANE_Y = -1.75
FAR_X = 1000.0  # x of pedestrians that must stay outside the grid window
_PED_FIELDS = {f.name for f in dataclasses.fields(PedestrianState)}


# --- fixtures and scene builders ---------------------------------------------


@pytest.fixture(scope="module")
def env(env_params):
    return env_params[0]


@pytest.fixture(scope="module")
def params(env_params):
    return env_params[1]


@pytest.fixture(scope="module")
def static(env):
    return env.static


def _scan_steps(env, state, key, fixed_action, use_rule, params):
    """``SCAN_STEPS`` steps of ``env.step_env``; action fixed or rule-based."""
    rb = RuleBasedParams()

    def body(st, k):
        rule = rule_based_action(st, params, rb, env.static)
        action = jnp.where(use_rule, rule, fixed_action).astype(jnp.int32)
        _, nxt, r, term, trunc, info = env.step_env(k, st, action, params)
        out = {
            "action": action,
            "v": nxt.ego.v,
            "s": nxt.ego.s,
            "ped_position": nxt.pedestrians.position,
            "waypoint_index": nxt.pedestrians.waypoint_index,
            "collision": info["collision"],
            "struck_while_stopped": info["struck_while_stopped"],
            "terminated": term,
            "truncated": trunc,
            "reward": r,
            "ttc": info["ttc"],
        }
        return nxt, out

    return jax.lax.scan(body, state, jax.random.split(key, SCAN_STEPS))


@pytest.fixture(scope="module")
def run_scene(env):
    jitted = jax.jit(functools.partial(_scan_steps, env))

    def run(state, params, *, action=ACCELERATE, rule=False, seed=0):
        final, out = jitted(
            state, jax.random.key(seed), jnp.int32(action), jnp.asarray(rule), params
        )
        return final, jax.tree.map(np.asarray, out)

    return run


@pytest.fixture(scope="module")
def raster(static):
    return jax.jit(rasterize_grid, static_argnums=3)


@pytest.fixture(scope="module")
def ttc_fn(static):
    return jax.jit(time_to_collision, static_argnums=3)


def _ego(params, static, *, s: float = 5.0, v: float = 0.0) -> EgoState:
    """Ego at arc length ``s`` and speed ``v`` (setpoint v, no acceleration)."""
    return initial_ego(params, static).replace(
        s=jnp.float32(s), v=jnp.float32(v), v_setpoint=jnp.float32(v)
    )


def _peds(
    static,
    positions,
    *,
    targets=None,
    speeds=None,
    velocities=None,
    headings=None,
    park_x: float = 40.0,
    park_y: float = 5.0,
) -> PedestrianState:
    """P pedestrians: the given ones first, the rest standing on the left sidewalk.

    A pedestrian with speed 0 stands still forever (its target differs from its
    position, so it never "arrives" and is never replaced as done). Parked
    pedestrians stand at ``x = park_x + i``, ``y = park_y``.
    """
    num = static.num_pedestrians
    n = len(positions)
    assert n <= num
    pos = np.zeros((num, 2), np.float32)
    pos[:n] = np.asarray(positions, np.float32).reshape(n, 2)
    pos[n:, 0] = park_x + np.arange(num - n)
    pos[n:, 1] = park_y
    tgt = pos + np.array([0.0, 5.0], np.float32)  # standing: a target it never walks to
    if targets is not None:
        tgt[:n] = np.asarray(targets, np.float32).reshape(n, 2)
    spd = np.zeros(num, np.float32)
    if speeds is not None:
        spd[:n] = speeds
    vel = np.zeros((num, 2), np.float32)
    if velocities is not None:
        vel[:n] = np.asarray(velocities, np.float32).reshape(n, 2)
    head = np.arctan2(tgt[:, 1] - pos[:, 1], tgt[:, 0] - pos[:, 0]).astype(np.float32)
    if headings is not None:
        head[:n] = headings
    fields = {
        "position": jnp.asarray(pos),
        "velocity": jnp.asarray(vel),
        "heading": jnp.asarray(head),
        "desired_speed": jnp.asarray(spd),
        "behaviour": jnp.full((num,), CROSSING, jnp.int32),
        "waypoints": jnp.asarray(np.repeat(tgt[:, None, :], NUM_WAYPOINTS, axis=1)),
        "waypoint_index": jnp.zeros((num,), jnp.int32),
        "waited": jnp.zeros((num,), jnp.float32),
        "visible": jnp.ones((num,), bool),
    }
    if "speed" in _PED_FIELDS:  # the norm of the velocity, stored where the step knows it
        fields["speed"] = jnp.asarray(np.linalg.norm(vel, axis=-1).astype(np.float32))
    return PedestrianState(**fields)


def _state(ego: EgoState, peds: PedestrianState) -> EnvState:
    return EnvState(
        ego=ego,
        pedestrians=peds,
        last_action=jnp.int32(-1),
        time=jnp.int32(0),
    )


def _box_distance(px, py, s, params, inflate: float = 0.0):
    """Euclidean distance (float64) from points to the ego box at ``s`` (0 inside)."""
    half_x = 0.5 * params.ego_length + inflate
    half_y = 0.5 * params.ego_width + inflate
    dx = np.maximum(np.abs(np.asarray(px, np.float64) - s) - half_x, 0.0)
    dy = np.maximum(np.abs(np.asarray(py, np.float64) - LANE_Y) - half_y, 0.0)
    return np.hypot(dx, dy)


def _first_index(mask) -> int:
    hits = np.flatnonzero(np.asarray(mask))
    assert hits.size > 0, "condition never reached"
    return int(hits[0])


def test_lane_centre(params):
    assert float(lane_centre_y(params)) == LANE_Y


# --- 1. driving into a standing pedestrian -------------------------------------


def test_accelerating_into_standing_pedestrian_collides(env, params, static, run_scene):
    """``collision_model = "contact"``: the collision is the step the box meets the disc."""
    params = params.replace(collision_model="contact")
    s0 = float(params.ego_start_s)
    ped_xy = (s0 + 8.0, LANE_Y)
    state = _state(_ego(params, static, s=s0), _peds(static, [ped_xy]))
    _, out = run_scene(state, params, action=ACCELERATE)

    hit = _first_index(out["collision"])
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


# --- 2. time to collision ----------------------------------------------------------


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
    ego = _ego(params, static, s=s, v=v)
    peds = _peds(static, [(s + d, LANE_Y)], park_x=s + 60.0)
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
    ego = _ego(params, static, s=s, v=v)
    peds = _peds(static, [(s + d, y)], park_x=s + 60.0)
    assert math.isinf(float(ttc_fn(ego, peds, params, static)))


def test_ttc_moving_pedestrian_and_minimum(params, static, ttc_fn):
    s, v = 20.0, 4.0
    ego = _ego(params, static, s=s, v=v)
    # Walking from the left lane (y = 1.25) towards the ego's lane at 1 m/s:
    # at t = 1.8 s dx = 0.55 m (apart), at t = 1.9 s dx = 0.15, dy = 0.2,
    # distance 0.25 < 0.3 (overlap) -> TTC 1.9.
    crossing = (s + 10.0, 1.25)
    peds = _peds(static, [crossing], velocities=[(0.0, -1.0)], speeds=[1.0], park_x=s + 60.0)
    assert float(ttc_fn(ego, peds, params, static)) == pytest.approx(1.9, abs=1e-6)
    # The same pedestrian standing still is never in the path.
    still = _peds(static, [crossing], park_x=s + 60.0)
    assert math.isinf(float(ttc_fn(ego, still, params, static)))
    # Minimum over pedestrians: add one standing at 6.0 m (gap 3.45 m -> 0.9 s).
    both = _peds(
        static,
        [crossing, (s + 6.0, LANE_Y)],
        velocities=[(0.0, -1.0), (0.0, 0.0)],
        park_x=s + 60.0,
    )
    assert float(ttc_fn(ego, both, params, static)) == pytest.approx(0.9, abs=1e-6)


def test_step_reports_ttc_and_near_collision_reward(env, params, static, ttc_fn):
    s, v = 20.0, 4.0
    state = _state(_ego(params, static, s=s, v=v), _peds(static, [(s + 10.0, LANE_Y)]))
    stepped, r, terminated, _, info = jax.jit(env.advance)(state, jnp.int32(STEER), params)
    ttc = float(info["ttc"])
    assert ttc == float(ttc_fn(stepped.ego, stepped.pedestrians, params, static))
    # After one step the gap is 7.45 - (about 0.4) m at about 4 m/s: 1.8 s.
    assert ttc == pytest.approx(1.8, abs=1e-6)
    assert float(r) == pytest.approx(ttc - params.ttc_threshold, abs=1e-6)
    assert not bool(terminated) and not bool(info["collision"])


# --- 3. rule-based agent stops short of a standing pedestrian ----------------------


@pytest.mark.parametrize("v0_kmh", [0.0, 15.0])
def test_rule_based_stops_before_standing_pedestrian(env, params, static, run_scene, v0_kmh):
    s0 = float(params.ego_start_s)
    ped_x = s0 + 30.0
    state = _state(_ego(params, static, s=s0, v=v0_kmh * KMH), _peds(static, [(ped_x, LANE_Y)]))
    final, out = run_scene(state, params, rule=True)

    assert not np.any(out["collision"])
    assert not np.any(out["terminated"])
    assert float(final.ego.v) == 0.0
    assert np.all(out["v"][-50:] == 0.0), "the ego does not stay stopped"
    gap = ped_x - params.ped_radius - (float(final.ego.s) + 0.5 * params.ego_length)
    rb = RuleBasedParams()
    assert 0.0 < gap <= rb.lookahead
    # It drove at the speed limit before braking (within the ±1 km/h band).
    assert np.max(out["v"]) >= (15.0 - 1.0) * KMH
    assert np.max(out["v"]) <= (15.0 + 1.5) * KMH
    # First brake only once the pedestrian is within the look-ahead of the bumper.
    first_brake = _first_index(out["action"] == BRAKE)
    s_before = out["s"][first_brake - 1] if first_brake > 0 else s0
    assert ped_x - (s_before + 0.5 * params.ego_length) <= rb.lookahead
    assert np.all(out["action"][first_brake:] == BRAKE)
    # The standing pedestrian stayed where it was (never replaced, never moved).
    np.testing.assert_array_equal(
        out["ped_position"][:, 0], np.broadcast_to(np.float32([ped_x, LANE_Y]), (SCAN_STEPS, 2))
    )


def test_rule_based_labels_of_records_are_its_actions(params, static):
    """``rule_based_labels`` on the replay's records (``GridInputs``) gives the
    action ``rule_based_action`` takes in the true state, for any leading shape:
    braking for a pedestrian in the corridor within the look-ahead, not for one
    beyond it or on the sidewalk, and tracking the speed limit otherwise."""
    rb = RuleBasedParams()
    s = 40.0
    front = s + 0.5 * params.ego_length
    scenes = [
        (0.0, [(front + 3.0, LANE_Y)]),  # in the corridor: brake
        (4.0, [(front + rb.lookahead + 2.0, LANE_Y)]),  # beyond the look-ahead
        (4.2, [(front + 3.0, -5.0)]),  # on the sidewalk
        (3.0, [(front + 6.0, LANE_Y + 0.5)]),  # in the corridor, off-centre: brake
        (4.9, []),  # nobody: slow down from above the limit
        (2.0, []),  # nobody: accelerate
    ]
    states = [_state(_ego(params, static, s=s, v=v), _peds(static, peds)) for v, peds in scenes]
    batch = jax.tree.map(lambda *x: jnp.stack(x).reshape((2, 3, *x[0].shape)), *states)
    expected = [int(rule_based_action(st, params, rb, static)) for st in states]
    assert expected[0] == expected[3] == BRAKE and BRAKE not in expected[1:3] + expected[4:]
    records = GridInputs.of(batch.ego, batch.pedestrians)
    labels = rule_based_labels(records, params, rb, static)
    assert labels.shape == (2, 3)
    np.testing.assert_array_equal(np.asarray(labels).ravel(), expected)


def test_rule_based_horizon_anticipates_pedestrians_walking_into_the_corridor(params, static):
    """``horizon`` = h > 0: also brake for a pedestrian that, walking on, enters the
    corridor within h seconds, within the look-ahead of the bumper, before the bumper
    (moving on at the ego's speed) has passed it; h = 0 is the paper's rule."""
    s, v = 40.0, 4.0
    front = s + 0.5 * params.ego_length
    kerb = LANE_Y - 2.0  # 0.3 m outside the corridor (half width 0.9 + 0.3 + 0.5)
    scenes = {  # pedestrian (x, y), velocity, ego speed -> brakes with h = 0.1, 0.5, 1
        "steps in, enters in 0.2 s": ((front + 3.0, kerb), (0.0, 1.5), v, (0, 1, 1)),
        "steps in slowly, enters in 0.75 s": ((front + 3.0, kerb), (0.0, 0.4), v, (0, 0, 1)),
        "walks away": ((front + 3.0, kerb), (0.0, -1.5), v, (0, 0, 0)),
        "walks along the kerb": ((front + 3.0, kerb), (1.5, 0.0), v, (0, 0, 0)),
        "the bumper passes first": ((front + 0.2, kerb), (0.0, 1.5), v, (0, 0, 0)),
        "... unless the ego stands": ((front + 0.2, kerb), (0.0, 1.5), 0.0, (0, 1, 1)),
        "beyond the look-ahead": ((front + 8.0, kerb), (0.0, 1.5), v, (0, 0, 0)),
        "into the look-ahead in 0.4 s": ((front + 7.4, LANE_Y), (-1.0, 0.0), v, (0, 1, 1)),
        "standing beyond it": ((front + 7.5, LANE_Y), (0.0, 0.0), v, (0, 0, 0)),
    }
    action = jax.jit(rule_based_action, static_argnums=3)
    labels = jax.jit(rule_based_labels, static_argnums=3)
    for name, (position, velocity, speed, brakes) in scenes.items():
        state = _state(
            _ego(params, static, s=s, v=speed), _peds(static, [position], velocities=[velocity])
        )
        records = GridInputs.of(state.ego, state.pedestrians)  # what the replay holds
        for horizon, want in zip((0.0, 0.1, 0.5, 1.0), (0, *brakes), strict=True):
            rb = RuleBasedParams(horizon=horizon)
            got = int(action(state, params, rb, static))
            assert (got == BRAKE) == bool(want), (name, horizon)
            assert int(labels(records, params, rb, static)) == got


# --- 4. pedestrians never walk into the car ------------------------------------------


def test_pedestrians_stop_before_stopped_car(env, params, static, run_scene):
    """``ped_behaviour_to_car = "yield"`` (with a wait longer than the scene)."""
    params = params.replace(ped_behaviour_to_car="yield", ped_wait_max_s=100.0)
    s = 20.0
    walkers = [
        # (start, target, speed m/s)
        ((20.0, -4.75), (20.0, 3.0), 1.4),  # from the right sidewalk straight across
        ((20.5, 1.5), (20.5, -6.0), 1.4),  # from the left lane down across the car
        ((27.0, LANE_Y), (5.0, LANE_Y), 1.4),  # head-on along the lane centre
        ((24.0, 1.0), (16.0, -5.0), 1.0),  # diagonally through the car
        ((14.0, LANE_Y), (30.0, LANE_Y), 1.2),  # from behind into the rear
        ((15.0, -5.0), (25.0, 2.0), 1.5),  # towards the rear right corner
        ((22.0, -4.0), (22.0, 2.0), 0.3),  # at the paper's walking speed
    ]
    starts = [w[0] for w in walkers]
    state = _state(
        _ego(params, static, s=s, v=0.0),
        _peds(
            static,
            starts,
            targets=[w[1] for w in walkers],
            speeds=[w[2] for w in walkers],
            park_x=s + 10.0,
        ),
    )
    _, out = run_scene(state, params, action=BRAKE)

    assert np.all(out["v"] == 0.0) and np.all(out["s"] == np.float32(s))
    assert not np.any(out["collision"])
    assert not np.any(out["terminated"])
    n = len(walkers)
    pos = out["ped_position"][:, :n]  # (T, n, 2)
    # Never inside the box inflated by the clearance (discs only touch it at most).
    dist = _box_distance(pos[..., 0], pos[..., 1], s, params, inflate=params.ped_clearance)
    assert np.all(dist >= params.ped_radius - 1e-5), dist.min()
    # The package's own overlap test agrees at every step.
    centre, half = ego_box(jnp.float32(s), params, inflate=params.ped_clearance)
    overlap = box_disc_overlap(centre, half, jnp.asarray(pos), params.ped_radius)
    assert not np.any(np.asarray(overlap))
    # Each walker really walked up to the car: it stands within one step of the
    # inflated footprint, is not done, and never moved again.
    end = pos[-1]
    end_dist = _box_distance(end[:, 0], end[:, 1], s, params, inflate=params.ped_clearance)
    step = np.array([w[2] for w in walkers]) * params.dt
    assert np.all(end_dist - params.ped_radius < step + 1e-5), (end_dist, step)
    moved = np.linalg.norm(end - np.asarray(starts, np.float32), axis=-1)
    assert np.all(moved > 0.5)
    assert np.all(out["waypoint_index"][-1, :n] == 0)
    np.testing.assert_array_equal(pos[-20:], np.broadcast_to(end, (20, n, 2)))


def _walker_across_stopped_car(params, static):
    """The car stands at s = 20 (box x in [17.75, 22.25], y in [-2.65, -0.85]); a
    walker at the paper's speed, 0.3 m/s (0.03 m a step), starts at (22, -4) and
    crosses towards the left sidewalk: its disc (radius 0.3 m) meets the box once
    it has walked 1.05 m, at step 35; its centre enters the ego's lane (y = -3.5)
    after 0.5 m, at step 17."""
    s = 20.0
    return _state(
        _ego(params, static, s=s, v=0.0),
        _peds(static, [(22.0, -4.0)], targets=[(22.0, 2.0)], speeds=[0.3], park_x=s + 10.0),
    )


@pytest.mark.parametrize(("model", "steps"), [("contact", (34, 35, 36)), ("authors", (17, 18))])
def test_ignoring_pedestrian_strikes_stopped_car(params, static, run_scene, model, steps):
    """``ped_behaviour_to_car = "ignore"`` (the paper's world): the walker walks on
    into the stopped car. It is *struck while stopped* (SPEC §5): not the ego's
    collision, no penalty, and the episode goes on."""
    params = params.replace(ped_behaviour_to_car="ignore", collision_model=model)
    _, out = run_scene(_walker_across_stopped_car(params, static), params, action=BRAKE)

    assert np.all(out["v"] == 0.0)  # the car never moved: the walker did
    assert not np.any(out["collision"]) and not np.any(out["terminated"])
    first = int(np.argmax(out["struck_while_stopped"]))
    assert out["struck_while_stopped"][first] and first + 1 in steps, first
    assert np.all(out["reward"] == np.float32(params.reward_stopped))  # never r_c
    if model == "contact":
        walked = 4.0 + out["ped_position"][first, 0, 1]
        assert 1.05 - 1e-4 <= walked < 1.05 + 0.03 + 1e-4, walked
    # it walks on through the car and out of the lane: the strike ends
    assert out["ped_position"][-1, 0, 1] > 0.0 and not out["struck_while_stopped"][-1]


def test_yielding_pedestrian_walks_on_after_its_wait(params, static, run_scene):
    """``"yield"`` waits at most ``ped_wait_max_s`` (5 s: CARLA's), then walks on:
    never a standoff (SPEC §3). It stops one step short of the inflated box, stands
    50 steps, then walks into the stopped car: struck while stopped."""
    params = params.replace(ped_behaviour_to_car="yield", collision_model="contact")
    _, out = run_scene(_walker_across_stopped_car(params, static), params, action=BRAKE)

    y = out["ped_position"][:, 0, 1]
    standing = np.flatnonzero(np.diff(y) == 0.0) + 1
    assert standing.size > 0
    waited = standing[-1] - standing[0] + 1
    assert waited == round(float(params.ped_wait_max_s) / float(params.dt)), waited
    assert np.all(np.diff(standing) == 1)  # one wait, then on
    assert y[-1] > y[standing[-1]]
    assert np.any(out["struck_while_stopped"]) and not np.any(out["collision"])
    assert not np.any(out["terminated"])


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
        state = _state(_ego(p, static, s=5.0, v=15 / 3.6), _peds(static, [(20.0, y)]))
        _, out = run_scene(state, p, action=STEER)
        hits[model] = np.flatnonzero(out["collision"])
    assert (hits["contact"].size > 0) == contact and (hits["authors"].size > 0) == authors
    if contact and authors:
        assert hits["authors"][0] < hits["contact"][0]


# --- 5. the observation grid ----------------------------------------------------


def _grid_scene(params, static, positions, **kw):
    ego = _ego(params, static, s=20.0)
    return ego, _peds(static, positions, park_x=FAR_X, **kw)


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


def test_nearest_wins_pairwise_equals_the_mask_form(monkeypatch):
    # P = 12 pedestrians in 4 cells with many exact distance ties: the pairwise
    # form (P <= PAIRWISE_MAX_PEDESTRIANS) and the (P, P) mask form agree.
    from drqn_jax.env import grid

    rng = np.random.default_rng(0)
    flat = jnp.asarray(rng.integers(0, 4, (50, 12)), jnp.int32)
    dist2 = jnp.asarray(rng.integers(0, 3, (50, 12)), jnp.float32)
    pairwise = jax.vmap(grid._nearest_wins, (0, 0, None))(flat, dist2, 1350)
    monkeypatch.setattr(grid, "PAIRWISE_MAX_PEDESTRIANS", 0)
    mask = jax.vmap(grid._nearest_wins, (0, 0, None))(flat, dist2, 1350)
    np.testing.assert_array_equal(np.asarray(pairwise), np.asarray(mask))
    kept = np.asarray(pairwise) < 1350
    for row in range(50):  # one winner per occupied cell
        assert sorted(np.asarray(flat)[row][kept[row]]) == sorted(set(np.asarray(flat)[row]))


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


# --- 6. semantic map -------------------------------------------------------------


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
