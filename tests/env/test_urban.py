"""The env (drqn_jax/env/urban.py) keeps the gymnax 1.0 contract: make/reset/step,
auto-reset, terminal flags, determinism, jit ≡ eager, vmap ≡ loop, batch independence.

``drqn_jax.testing.check_env_contract`` (the checker users run on their own envs)
runs on every registered world; the tests after it check what it cannot know:
the info keys, invalid actions, long rollouts, large batches, hand-built endings.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax
from drqn_jax.env.params import EnvParams
from drqn_jax.env.state import ACCELERATE, BRAKE, NO_ACTION, NUM_WAYPOINTS, STEER
from drqn_jax.registry import registered_envs
from drqn_jax.testing import check_env_contract
from tests.helpers import (
    assert_tree_equal,
    batched_rollout_summary,
    bit_hash,
    fast_jit,
    random_rollout,
    take,
    tree_equal,
)


@pytest.fixture(scope="module")
def jit_step(env_params):
    env, _ = env_params
    return jax.jit(env.step)


@pytest.fixture(scope="module")
def jit_step_env(env_params):
    env, _ = env_params
    return jax.jit(env.step_env)


#: Episodes of the checker's worlds: 16 steps, so each of its envs ends at least two
#: within its 40 steps and the auto-reset is checked (the worlds' own 1000 below).
CONTRACT_MAX_STEPS, CONTRACT_STEPS, CONTRACT_ENVS = 16, 40, 4


@pytest.mark.parametrize("env_id", registered_envs())
def test_every_registered_world_keeps_the_contract(env_id):
    """The shared checker on each world: types and shapes, observations in the
    space, finite rewards, auto-reset, same key ≡ same rollout, jit ≡ no jit (one
    step); worlds of one static shape share its compiled rollout."""
    env, params = drqn_jax.make(env_id, max_steps=CONTRACT_MAX_STEPS)
    report = check_env_contract(
        env,
        params,
        key=jax.random.key(17),
        num_envs=CONTRACT_ENVS,
        num_steps=CONTRACT_STEPS,
        eager_steps=1,
    )
    assert report.resets >= 2 * CONTRACT_ENVS, report
    assert -10.0 <= report.reward_min <= report.reward_max <= 1.0, report


def test_make_returns_env_and_params(env_params):
    env, params = env_params
    assert isinstance(env, drqn_jax.UrbanPedestrians)
    assert isinstance(params, EnvParams)
    assert env.num_actions == 4
    assert hash(env) == hash(drqn_jax.make()[0])  # static and hashable: jit cache hits
    obs, state = env.reset(jax.random.key(0), params)
    assert obs.grid.shape == (45, 30, 4) and obs.grid.dtype == jnp.float32
    assert obs.speed.shape == () and obs.speed.dtype == jnp.float32
    assert obs.last_action.shape == () and int(obs.last_action) == NO_ACTION
    assert state.pedestrians.position.shape == (10, 2)
    assert env.observation_space(params).contains(obs)
    assert env.action_space(params).n == 4


def test_step_returns_six_tuple_with_info(env_params, jit_step):
    env, params = env_params
    _, state = env.reset(jax.random.key(0), params)
    out = jit_step(jax.random.key(1), state, ACCELERATE, params)
    assert len(out) == 6
    obs, state2, reward, terminated, truncated, info = out
    assert reward.dtype == jnp.float32 and reward.shape == ()
    assert terminated.dtype == jnp.bool_ and truncated.dtype == jnp.bool_
    for name in (
        "collision",
        "struck_while_stopped",
        "goal",
        "ttc",
        "distance",
        "speed",
        "time",
        "invalid_action",
        "final_observation",
    ):
        assert name in info
    assert int(info["time"]) == 1 and int(state2.time) == 1
    assert int(obs.last_action) == ACCELERATE
    assert float(state2.ego.v) > 0.0


def test_actions_outside_the_space_are_clipped_and_flagged(env_params):
    """SPEC §2: an integer outside 0-3 acts as its nearest action, flagged in
    ``info["invalid_action"]`` and never stored as ``last_action``; a non-integer
    action is refused when traced."""
    env, params = env_params
    _, state = env.reset(jax.random.key(0), params)
    step = jax.jit(env.step_env)
    for action, acts_as in ((7, STEER), (-1, ACCELERATE), (2, BRAKE)):
        _, nxt, *_, info = step(jax.random.key(1), state, jnp.int32(action), params)
        _, ref, *_ = step(jax.random.key(1), state, jnp.int32(acts_as), params)
        assert bool(info["invalid_action"]) == (action != acts_as)
        assert int(nxt.last_action) == acts_as
        assert float(nxt.ego.v_setpoint) == float(ref.ego.v_setpoint)
    with pytest.raises(TypeError, match=r"action: dtype float32 is not an integer"):
        env.step_env(jax.random.key(1), state, jnp.float32(1.5), params)


def test_vmap_over_params(env_params):
    """A batch of EnvParams is swept in one program and equals separate runs."""
    env, _ = env_params
    speeds = [0.1, 0.3, 1.0]
    plist = [EnvParams(ped_speed_min=s, ped_speed_max=s) for s in speeds]
    batched = jax.tree.map(lambda *xs: jnp.stack(xs), *plist)
    keys = jax.random.split(jax.random.key(5), len(speeds))

    def run(params, key):
        out, _ = random_rollout(env, params, key, 20)
        return out

    together = jax.jit(jax.vmap(run))(batched, keys)
    for i, p in enumerate(plist):
        assert_tree_equal(take(together, i), jax.jit(run)(p, keys[i]))
    speeds_seen = together[4]["speed"]
    assert speeds_seen.shape == (3, 20)


def test_jit_matches_eager(env_params):
    """Eager (op by op) and jit agree bitwise over a few steps.

    This holds because ``import drqn_jax`` turns off FMA contraction in XLA:CPU
    (see ``drqn_jax.determinism``); with it, ``jit`` fuses ``a + b*c`` into one
    rounding and eager does two.
    """
    env, params = env_params
    key = jax.random.key(11)
    _, state = env.reset(key, params)
    step_jit = jax.jit(env.step)
    s_eager, s_jit = state, state
    for i, action in enumerate([ACCELERATE] * 6 + [STEER, BRAKE]):
        k = jax.random.fold_in(key, i)
        out_e = env.step(k, s_eager, action, params)
        out_j = step_jit(k, s_jit, action, params)
        assert_tree_equal(out_e, out_j)
        s_eager, s_jit = out_e[1], out_j[1]


def test_reset_jit_matches_eager_bitwise(env_params):
    env, params = env_params
    key = jax.random.key(4)
    assert_tree_equal(env.reset(key, params), jax.jit(env.reset)(key, params))


def test_vmap_matches_python_loop(env_params, jit_step):
    """vmap over 64 envs ≡ a Python loop of single envs, bitwise."""
    env, params = env_params
    n, steps = 64, 12
    keys = jax.random.split(jax.random.key(2), n)
    _, states = jax.jit(jax.vmap(env.reset, (0, None)))(keys, params)
    actions = jax.random.randint(jax.random.key(3), (steps, n), 0, 4)
    step_keys = jax.random.split(jax.random.key(4), (steps, n))
    vstep = jax.jit(jax.vmap(env.step, (0, 0, 0, None)))
    batched = states
    outs = []
    for t in range(steps):
        out = vstep(step_keys[t], batched, actions[t], params)
        batched = out[1]
        outs.append(out)
    outs = jax.device_get(outs)  # NumPy leaves: 768 slices of them cost nothing
    for i in range(n):
        single = take(states, i)
        for t in range(steps):
            out = jit_step(step_keys[t, i], single, actions[t, i], params)
            single = out[1]
            assert tree_equal(out, take(outs[t], i)), (i, t)


def test_same_key_bit_identical_1000_steps(env_params):
    env, params = env_params
    keys = jax.random.split(jax.random.key(7), 8)
    a = batched_rollout_summary(env, params, keys, 1000)
    b = batched_rollout_summary(env, params, keys, 1000)
    assert_tree_equal(a, b)
    summary, _ = a
    # the rollout really is 1000 steps of a living world
    assert summary["reward"].shape == (8, 1000)
    assert np.any(np.asarray(summary["terminated"]) | np.asarray(summary["truncated"]))
    other, _ = batched_rollout_summary(env, params, jax.random.split(jax.random.key(8), 8), 1000)
    assert not np.array_equal(np.asarray(other["reward"]), np.asarray(summary["reward"]))


def test_episode_independent_of_batch(env_params):
    """Episode i is identical alone (unbatched, or a batch of 1) and among 256 others."""
    env, params = env_params
    steps = 300
    keys = jax.random.split(jax.random.key(9), 256)
    many = batched_rollout_summary(env, params, keys, steps)
    for i in (0, 77, 255):
        alone = batched_rollout_summary(env, params, keys[i : i + 1], steps)
        assert_tree_equal(take(many, i), take(alone, 0))
    single = jax.jit(lambda k: random_rollout(env, params, k, steps))(keys[77])
    (obs, r, _term, _trunc, _info), state = single
    assert np.array_equal(np.asarray(r), np.asarray(many[0]["reward"][77]))
    assert np.array_equal(np.asarray(bit_hash(obs.grid, (1, 2, 3))), many[0]["grid_hash"][77])
    assert_tree_equal(state, take(many[1], 77))


def test_make_under_jit_vmap_1024(env_params):
    env, params = env_params
    n = 1024

    @fast_jit
    def run(key):
        keys = jax.random.split(key, n)
        _obs, state = jax.vmap(env.reset, (0, None))(keys, params)
        actions = jnp.full((n,), ACCELERATE)
        return jax.vmap(env.step, (0, 0, 0, None))(keys, state, actions, params)

    obs, state, reward, terminated, truncated, _info = run(jax.random.key(0))
    assert obs.grid.shape == (n, 45, 30, 4)
    assert reward.shape == terminated.shape == truncated.shape == (n,)
    assert state.pedestrians.position.shape == (n, 10, 2)
    assert_tree_equal(run(jax.random.key(0)), run(jax.random.key(0)))


# --- terminal contract ---------------------------------------------------------


def _scene_with_pedestrian_at(env, params, x, y, key=0):
    """A reset state whose pedestrian 0 stands at (x, y) and the rest stand far away."""
    _, state = env.reset(jax.random.key(key), params)
    peds = state.pedestrians
    num = peds.position.shape[0]
    pos = jnp.tile(jnp.array([[-1000.0, 100.0]]), (num, 1)).at[0].set(jnp.array([x, y]))
    peds = peds.replace(
        position=pos,
        velocity=jnp.zeros_like(peds.velocity),
        desired_speed=jnp.zeros_like(peds.desired_speed),
        waypoints=jnp.repeat(pos[:, None], NUM_WAYPOINTS, axis=1),
        waypoint_index=jnp.zeros((num,), jnp.int32),
    )
    return state.replace(pedestrians=peds)


def test_collision_terminates_and_auto_resets(env_params, jit_step, jit_step_env):
    env, params = env_params
    state = _scene_with_pedestrian_at(env, params, 0.0, -1.75)
    # ego centre at 5 m moving at 5 m/s: its rear-to-front box reaches a pedestrian
    # standing 2.25 + 0.3 + 0.2 m ahead of its centre within one step
    state = state.replace(
        ego=state.ego.replace(v=jnp.float32(5.0)),
        pedestrians=state.pedestrians.replace(
            position=state.pedestrians.position.at[0].set(jnp.array([5.0 + 2.6, -1.75]))
        ),
    )
    key = jax.random.key(21)
    obs, new_state, reward, terminated, truncated, info = jit_step(key, state, STEER, params)
    assert bool(info["collision"]) and bool(terminated) and not bool(truncated)
    assert float(reward) == -10.0
    # the returned state and observation are exactly reset(key)'s
    reset_obs, reset_state = env.reset(key, params)
    assert_tree_equal(new_state, reset_state)
    assert_tree_equal(obs, reset_obs)
    # the final observation is exactly what step_env returns
    obs_env, state_env, *_ = jit_step_env(key, state, STEER, params)
    assert_tree_equal(info["final_observation"], obs_env)
    assert int(state_env.time) == 1 and int(new_state.time) == 0


def test_goal_terminates(env_params, jit_step):
    env, params = env_params
    state = _scene_with_pedestrian_at(env, params, -500.0, 100.0)
    state = state.replace(ego=state.ego.replace(s=jnp.float32(199.9), v=jnp.float32(4.0)))
    _, new_state, _reward, terminated, truncated, info = jit_step(
        jax.random.key(1), state, STEER, params
    )
    assert bool(info["goal"]) and bool(terminated) and not bool(truncated)
    assert not bool(info["collision"])
    assert float(new_state.ego.s) == float(params.ego_start_s)  # fresh episode


def test_truncation_at_max_steps(env_params, jit_step):
    """Step 1000 truncates (not terminates); every earlier step does neither here."""
    env, params = env_params
    state = _scene_with_pedestrian_at(env, params, -500.0, 100.0)

    @fast_jit
    def run(state):
        def body(state, k):
            # stand still (brake): no goal, and pedestrians keep respawning far ahead
            _, state, _r, term, trunc, info = env.step(k, state, BRAKE, params)
            return state, (term, trunc, info["time"])

        return jax.lax.scan(body, state, jax.random.split(jax.random.key(3), 1001))

    _, (term, trunc, time) = run(state)
    term, trunc, time = np.asarray(term), np.asarray(trunc), np.asarray(time)
    assert not term.any()
    assert trunc[999] and not trunc[:999].any()
    assert time[999] == 1000 and time[1000] == 1  # the step after truncation is a new episode


def test_truncated_final_observation_and_fresh_state(env_params, jit_step, jit_step_env):
    env, params = env_params
    state = _scene_with_pedestrian_at(env, params, -500.0, 100.0)
    state = state.replace(time=jnp.int32(999))
    key = jax.random.key(5)
    obs, new_state, _, terminated, truncated, info = jit_step(key, state, ACCELERATE, params)
    assert bool(truncated) and not bool(terminated)
    assert_tree_equal((obs, new_state), env.reset(key, params))
    obs_env, _, _, _, trunc_env, _ = jit_step_env(key, state, ACCELERATE, params)
    assert bool(trunc_env)
    assert_tree_equal(info["final_observation"], obs_env)
    assert int(info["final_observation"].last_action) == ACCELERATE
    assert int(obs.last_action) == NO_ACTION


def test_step_equals_step_env_while_running(env_params, jit_step, jit_step_env):
    env, params = env_params
    _, state = env.reset(jax.random.key(0), params)
    for t in range(5):
        key = jax.random.key(100 + t)
        a = jit_step(key, state, ACCELERATE, params)
        b = jit_step_env(key, state, ACCELERATE, params)
        assert not bool(a[3] | a[4])
        assert_tree_equal(a[:5], b[:5])
        state = a[1]
