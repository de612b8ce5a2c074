"""Pedestrians (drqn_jax/env/pedestrians.py; SPEC §3): spawning, paths, walking,
replacement and occlusion, and how they meet the car in hand-built scenes
(``tests/scenes.py``): yielding ones stop short of it and walk on after their
wait, heedless ones strike the stopped car."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.collision import box_disc_overlap, ego_box
from drqn_jax.env.params import EnvParams
from drqn_jax.env.pedestrians import (
    RESPAWN_GATHER_SHARE,
    despawn_mask,
    respawn_pedestrians,
    sidewalk_x,
    spawn_pedestrians,
)
from drqn_jax.env.road_map import CROSSING_AREA, ROAD, WALKWAY, semantic_class
from drqn_jax.env.state import BRAKE, CROSSING, JAYWALKING, NUM_WAYPOINTS, SIDEWALK
from tests import scenes
from tests.helpers import fast_jit
from tests.scenes import LANE_Y, box_distance, make_ego, make_peds, make_state


@pytest.fixture(scope="module")
def run_scene(env):
    return functools.partial(scenes.run_scene, env)


@pytest.fixture(scope="module")
def spawned(env_params):
    env, params = env_params
    keys = jax.random.split(jax.random.key(0), 4000)
    spawn = jax.jit(jax.vmap(spawn_pedestrians, (0, None, None, None, None)), static_argnums=4)
    return spawn(keys, 0.0, 200.0, params, env.static)


def test_spawn_on_main_sidewalks_never_in_cross_streets(env_params, spawned):
    env, params = env_params
    pos = np.asarray(spawned.position).reshape(-1, 2)
    cls = np.asarray(semantic_class(jnp.asarray(pos), params, env.static))
    assert np.all(cls == WALKWAY)
    assert np.all((np.abs(pos[:, 1]) >= 3.5 + 0.3 - 1e-5) & (np.abs(pos[:, 1]) <= 6.5 - 0.3 + 1e-5))
    assert np.all((pos[:, 0] >= 0.0) & (pos[:, 0] < 200.0))
    # uniform over the sidewalk stretches: each 10 m bin outside streets gets its share
    inside = np.zeros(len(pos), bool)
    for xc in (50.0, 100.0, 150.0):
        inside |= np.abs(pos[:, 0] - xc) < 3.5
    assert not inside.any()
    counts, _ = np.histogram(pos[:, 0], bins=[0, 40, 60, 90, 110, 140, 160, 200])
    valid_len = np.array([40, 20 - 7, 30, 20 - 7, 30, 20 - 7, 40])
    np.testing.assert_allclose(counts / counts.sum(), valid_len / valid_len.sum(), atol=0.01)
    # both sidewalks
    assert 0.45 < np.mean(pos[:, 1] > 0) < 0.55


def test_sidewalk_x_skips_streets_exactly(env_params):
    env, params = env_params
    u = jnp.linspace(0.0, 0.999999, 10001)
    x = np.asarray(sidewalk_x(u, jnp.float32(40.0), jnp.float32(60.0), params, env.static))
    assert np.all(np.diff(x) >= 0)
    assert np.all(np.abs(x - 50.0) >= 3.5) and x.min() >= 40.0 and x.max() < 60.0


def test_behaviour_frequencies_follow_probabilities(env_params, spawned):
    b = np.asarray(spawned.behaviour).ravel()
    freq = np.bincount(b, minlength=3) / b.size
    np.testing.assert_allclose(freq, [0.6, 0.2, 0.2], atol=0.01)
    _, params = env_params
    speed = np.asarray(spawned.desired_speed).ravel()
    assert speed.min() >= float(params.ped_speed_min) and speed.max() <= float(params.ped_speed_max)


def test_paths_by_behaviour(env_params, spawned):
    env, params = env_params
    pos = np.asarray(spawned.position).reshape(-1, 2)
    wp = np.asarray(spawned.waypoints).reshape(-1, NUM_WAYPOINTS, 2)
    b = np.asarray(spawned.behaviour).ravel()
    # crossing: along the sidewalk to a crosswalk centre, across to the mirrored side
    c = b == CROSSING
    cw = np.array([50 - 5, 100 - 5, 150 - 5, 50 + 5, 100 + 5, 150 + 5], np.float32)
    assert np.all(np.min(np.abs(wp[c, 0, 0][:, None] - cw), axis=1) < 1e-4)
    np.testing.assert_array_equal(wp[c, 0, 1], pos[c, 1])
    np.testing.assert_array_equal(wp[c, 1, 0], wp[c, 0, 0])  # perpendicular crossing
    np.testing.assert_array_equal(wp[c, 1, 1], -pos[c, 1])
    cls_cross = np.asarray(
        semantic_class(jnp.asarray((wp[c, 0] + wp[c, 1]) / 2), params, env.static)
    )
    assert np.all(cls_cross == CROSSING_AREA)  # the crossing's midpoint is on the crosswalk
    walk_on = np.abs(wp[c, 2, 0] - wp[c, 1, 0])
    assert walk_on.min() >= 2.0 - 1e-4 and walk_on.max() <= 6.0 + 1e-4
    # jaywalking: across at 60-120 degrees to the road axis
    j = b == JAYWALKING
    d = wp[j, 0] - pos[j]
    angle = np.degrees(np.arctan2(np.abs(d[:, 1]), d[:, 0]))
    assert angle.min() >= 60 - 1e-3 and angle.max() <= 120 + 1e-3
    np.testing.assert_allclose(wp[j, 0, 1], -pos[j, 1])
    # sidewalk: along the same sidewalk, 10-30 m unless a cross street cuts it short
    s = b == SIDEWALK
    assert np.all(wp[s, :, 1] == pos[s, 1][:, None])
    length = np.abs(wp[s, 0, 0] - pos[s, 0])
    assert length.max() <= 30.0 + 1e-4
    assert np.mean(length >= 10.0 - 1e-4) > 0.5
    path_cls = np.asarray(semantic_class(jnp.asarray(wp[s].reshape(-1, 2)), params, env.static))
    assert np.all(path_cls == WALKWAY)


def test_pedestrians_walk_their_path_and_are_replaced(env_params):
    env, params = env_params
    params = EnvParams(ped_speed_min=1.0, ped_speed_max=1.0)  # fast, to finish paths
    _, state = env.reset(jax.random.key(3), params)

    @fast_jit
    def run(state):
        def body(state, k):
            _, state, *_ = env.step_env(k, state, 2, params)  # ego brakes: stands still
            return state, (state.pedestrians.behaviour, state.pedestrians.position)

        return jax.lax.scan(body, state, jax.random.split(jax.random.key(4), 400))

    final, (behaviour, position) = run(state)
    position = np.asarray(position)
    assert position.shape == (400, 10, 2)
    step = np.linalg.norm(np.diff(position, axis=0), axis=-1)
    moved = step[step > 0]
    # walking steps are at most speed·dt (replacements jump; exclude them by size)
    walking = moved[moved < 1.0]
    assert walking.size > 0 and walking.max() <= 0.1 + 1e-5
    # with fast pedestrians some finish their path and are replaced by new ones
    assert np.any(np.asarray(behaviour)[0] != np.asarray(behaviour)[-1]) or np.any(step > 1.0)
    assert not np.any(np.asarray(despawn_mask(final.pedestrians, final.ego, params)))


def test_road_is_entered_only_by_crossers_and_jaywalkers(env_params):
    env, params = env_params
    _, state = env.reset(jax.random.key(8), params)
    params_fast = EnvParams(ped_speed_min=1.0, ped_speed_max=1.5)

    @fast_jit
    def run(state):
        def body(state, k):
            _, state, *_ = env.step(k, state, 2, params_fast)
            peds = state.pedestrians
            return state, (peds.behaviour, semantic_class(peds.position, params, env.static))

        return jax.lax.scan(body, state, jax.random.split(jax.random.key(9), 1000))[1]

    behaviour, cls = (np.asarray(x) for x in run(state))
    on_road = (cls == ROAD) | (cls == CROSSING_AREA)
    assert on_road.any()  # pedestrians do cross
    assert not np.any(on_road & (behaviour == SIDEWALK))


@pytest.fixture(scope="module")
def occluded_rollout(env_params):
    """400 steps with ``occlusion_prob`` 0, 0.3 and 1 (one program, params traced):
    the states and grids, and the grid re-rasterised from a replay record."""
    from drqn_jax.env.grid import GridInputs, rasterize

    env, _ = env_params

    @jax.jit
    def run(params):
        _, state = env.reset(jax.random.key(5), params)

        def body(state, k):
            obs, state, *_ = env.step(k, state, 0, params)  # ego accelerates
            replayed = rasterize(GridInputs.of(state.ego, state.pedestrians), params, env.static)
            return state, (state.pedestrians, obs.grid, replayed)

        return jax.lax.scan(body, state, jax.random.split(jax.random.key(6), 400))[1]

    return {p: run(EnvParams(occlusion_prob=p)) for p in (0.0, 0.3, 1.0)}


def test_occlusion_hides_pedestrians_from_the_grid_only(occluded_rollout):
    """Hidden with probability p per pedestrian and step; the world is the same."""
    none, some, all_ = (occluded_rollout[p] for p in (0.0, 0.3, 1.0))
    assert bool(np.all(none[0].visible)) and not bool(np.any(all_[0].visible))
    hidden = 1.0 - float(np.mean(some[0].visible))
    assert 0.27 < hidden < 0.33  # 4000 draws: 0.3 ± 3 standard errors
    # pedestrians walk the same paths whatever the grid shows
    np.testing.assert_array_equal(some[0].position, none[0].position)
    assert float(np.asarray(all_[1])[..., 0].sum()) == 0.0  # an empty grid at p = 1
    occupied = np.asarray(some[1])[..., 0].sum(axis=(1, 2))
    assert np.all(occupied <= np.asarray(none[1])[..., 0].sum(axis=(1, 2)))
    assert np.any(occupied < np.asarray(none[1])[..., 0].sum(axis=(1, 2)))


def test_the_replay_record_reproduces_the_occluded_grid(occluded_rollout):
    _, grid, replayed = occluded_rollout[0.3]
    np.testing.assert_array_equal(replayed, grid)


def test_occlusion_draws_apart_from_the_spawns(env_params):
    """The occlusion uniforms come from ``fold_in(key, 1)``: at p = 0 the env is
    exactly the env without occlusion (the spawn draws are untouched)."""
    from drqn_jax.env.pedestrians import OCCLUSION_STREAM, occlusion_mask

    env, params = env_params
    key = jax.random.key(7)
    u = jax.random.uniform(jax.random.fold_in(key, OCCLUSION_STREAM), (10,))
    mask = occlusion_mask(key, EnvParams(occlusion_prob=0.5), env.static)
    np.testing.assert_array_equal(mask, u >= 0.5)
    lo, hi = (params.ego_start_s + params.spawn_initial_min, 45.0)
    assert float(lo) == 0.0 and float(params.ego_start_s + params.spawn_initial_max) == hi
    spawn = spawn_pedestrians(key, lo, hi, params, env.static)
    _, state = env.reset(key, params)
    np.testing.assert_array_equal(state.pedestrians.position, spawn.position)
    with pytest.raises(ValueError, match="occlusion_prob"):
        EnvParams(occlusion_prob=1.5)


def _respawn_every_env(keys, peds, replace, lo, hi, params, static):
    """The reference: every env draws P new pedestrians, taken where ``replace`` is set."""
    fresh = jax.vmap(spawn_pedestrians, (0, 0, 0, None, None))(keys, lo, hi, params, static)

    def pick(new, old):
        return jnp.where(replace.reshape(replace.shape + (1,) * (old.ndim - 2)), new, old)

    return jax.tree.map(pick, fresh, peds)


_ENVS = (0, 0, 0, 0, 0, None, None)
_respawn_one = jax.jit(respawn_pedestrians, static_argnums=6)
_respawn_envs = jax.jit(jax.vmap(respawn_pedestrians, _ENVS), static_argnums=6)
# Runs (params batched) × envs, as a vmapped sweep does.
_respawn_runs = jax.jit(
    jax.vmap(jax.vmap(respawn_pedestrians, _ENVS), (None,) * 5 + (0, None)), static_argnums=6
)


@pytest.mark.parametrize("num_needing", [0, 1, 3, 40])
def test_batched_respawn_equals_drawing_in_every_env(env_params, num_needing):
    # 64 envs: one gather pass takes 64 // RESPAWN_GATHER_SHARE = 2 envs, so 3 and 40
    # envs needing new pedestrians take 2 and 20 passes.
    env, params = env_params
    num_envs = 64
    assert num_envs // RESPAWN_GATHER_SHARE == 2
    k_old, k_new, k_mask = jax.random.split(jax.random.key(7), 3)
    keys = jax.random.split(k_new, num_envs)
    lo = jnp.linspace(0.0, 60.0, num_envs, dtype=jnp.float32)
    hi = lo + 40.0
    old = jax.vmap(spawn_pedestrians, (0, 0, 0, None, None))(
        jax.random.split(k_old, num_envs), lo, hi, params, env.static
    )
    envs = jax.random.permutation(k_mask, num_envs)[:num_needing]
    replace = jnp.zeros((num_envs, env.static.num_pedestrians), bool)
    replace = replace.at[envs, envs % env.static.num_pedestrians].set(True)
    replace = replace.at[envs, 0].set(True)
    expected = _respawn_every_env(keys, old, replace, lo, hi, params, env.static)
    changed = np.asarray(jnp.any(expected.position != old.position, axis=(1, 2)))
    assert changed.sum() == num_needing

    def assert_equal(got, want):
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    assert_equal(_respawn_envs(keys, old, replace, lo, hi, params, env.static), expected)
    runs = jax.tree.map(lambda x: jnp.stack([x, x]), params)
    nested = _respawn_runs(keys, old, replace, lo, hi, runs, env.static)
    assert_equal(nested, jax.tree.map(lambda x: jnp.stack([x, x]), expected))
    for e in (0, 9, 63):  # one env alone (the cond)
        env_e = jax.tree.map(lambda x, e=e: x[e], (keys, old, replace, lo, hi))
        single = _respawn_one(*env_e, params, env.static)
        assert_equal(single, jax.tree.map(lambda x, e=e: x[e], expected))


# --- pedestrians and the car (hand-built scenes) -----------------------------------


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
    state = make_state(
        make_ego(params, static, s=s, v=0.0),
        make_peds(
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
    dist = box_distance(pos[..., 0], pos[..., 1], s, params, inflate=params.ped_clearance)
    assert np.all(dist >= params.ped_radius - 1e-5), dist.min()
    # The package's own overlap test agrees at every step.
    centre, half = ego_box(jnp.float32(s), params, inflate=params.ped_clearance)
    overlap = box_disc_overlap(centre, half, jnp.asarray(pos), params.ped_radius)
    assert not np.any(np.asarray(overlap))
    # Each walker really walked up to the car: it stands within one step of the
    # inflated footprint, is not done, and never moved again.
    end = pos[-1]
    end_dist = box_distance(end[:, 0], end[:, 1], s, params, inflate=params.ped_clearance)
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
    return make_state(
        make_ego(params, static, s=s, v=0.0),
        make_peds(static, [(22.0, -4.0)], targets=[(22.0, 2.0)], speeds=[0.3], park_x=s + 10.0),
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
