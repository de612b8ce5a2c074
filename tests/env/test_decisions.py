"""Decisions every k ticks (``StaticEnvParams.decision_steps``; SPEC §2): one action
held for k ticks of ``dt`` is k ticks of the k = 1 env, and an episode ends at the
tick it ends."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.params import KMH, EnvParams, StaticEnvParams
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, STEER
from drqn_jax.env.urban import UrbanPedestrians
from tests.helpers import assert_tree_equal
from tests.scenes import LANE_Y, make_ego, make_peds, make_state

K = 5


def _ticks(env1, key, state, actions, params, k=K):
    """The k = 1 env's ``step_env`` once per action, tick ``i`` on ``split(key, k)[i]``
    (the keys of a k-tick decision): the observation and state after them, the summed
    reward, each tick's info."""
    total, infos = jnp.zeros((), jnp.float32), []
    for key_tick, action in zip(jax.random.split(key, k), actions, strict=False):
        obs, state, r, _, _, info = env1.step_env(key_tick, state, jnp.int32(action), params)
        total, infos = total + r, [*infos, info]
    return obs, state, total, infos


def _scene(static, params, v=2.0, ped_x=None):
    peds = make_peds(static, [] if ped_x is None else [(ped_x, LANE_Y)])
    return make_state(make_ego(params, static, s=20.0, v=v), peds)


def test_one_tick_decisions_are_the_ticks_themselves():
    """k = 1 (the default) is the env without the field: the same static settings
    (so the same compiled programs) and a step is ``advance`` then new pedestrians."""
    assert StaticEnvParams(decision_steps=1) == StaticEnvParams()
    env, params = UrbanPedestrians(), EnvParams()
    key = jax.random.key(3)
    _, state = env.reset(key)
    for i, action in enumerate([ACCELERATE, ACCELERATE, STEER, SLOW_DOWN, BRAKE]):
        step_key = jax.random.fold_in(key, i)
        got = env.step(step_key, state, jnp.int32(action), params)
        stepped, r, term, trunc, info = env.advance(state, jnp.int32(action), params)
        reset = term | trunc
        nxt = env._next_state(step_key, stepped, params, reset)
        assert_tree_equal(got[1], nxt)
        assert_tree_equal(got[0], env.observation(nxt, params))
        assert_tree_equal((got[2], got[3], got[4]), (r, term, trunc))
        assert set(got[5]) == {*info, "final_state", "final_observation"}
        state = got[1]


@pytest.mark.parametrize("action", [ACCELERATE, SLOW_DOWN, BRAKE, STEER])
def test_a_decision_is_k_ticks_of_the_one_tick_env(action):
    """``setpoint_change = "tick"``: a decision is exactly k ``step_env`` ticks of the
    k = 1 env under the same action: summed reward, final state and observation, and
    every tick's measurements in ``info["ticks"]``."""
    params = EnvParams(setpoint_change="tick")
    static = StaticEnvParams()
    env1 = UrbanPedestrians(static)
    envk = UrbanPedestrians(StaticEnvParams(decision_steps=K))
    state, key = _scene(static, params, ped_x=60.0), jax.random.key(1)
    obs, final, total, infos = _ticks(env1, key, state, [action] * K, params)
    got_obs, got_state, r, term, trunc, info = envk.step_env(key, state, jnp.int32(action), params)
    assert_tree_equal((got_obs, got_state), (obs, final))
    assert r == total and not term and not trunc
    for name in ("speed", "distance", "ttc", "collision", "time"):
        np.testing.assert_array_equal(info["ticks"][name], [i[name] for i in infos], name)
    assert info["ticks"]["played"].all()
    assert info["speed"] == infos[-1]["speed"] and info["time"] == state.time + K
    assert info["ttc"] == min(float(i["ttc"]) for i in infos)


def test_the_setpoint_changes_once_per_decision_by_default():
    """``setpoint_change = "decision"`` (the authors' 1-fps code): accelerate raises the
    setpoint by one step and the later ticks hold it, as ``steer`` holds it in the k = 1
    env under ``setpoint_mode = "setpoint"``."""
    params = EnvParams(setpoint_mode="setpoint")
    static = StaticEnvParams()
    envk = UrbanPedestrians(StaticEnvParams(decision_steps=K))
    state, key = _scene(static, params, v=2.0), jax.random.key(2)
    _, final, total, _ = _ticks(
        UrbanPedestrians(static), key, state, [ACCELERATE] + [STEER] * (K - 1), params
    )
    _, got, r, *_ = envk.step_env(key, state, jnp.int32(ACCELERATE), params)
    assert_tree_equal(got, final.replace(last_action=jnp.int32(ACCELERATE)))
    assert r == total
    assert np.isclose(float(got.ego.v_setpoint), 2.0 + KMH)
    per_tick = envk.step_env(
        key, state, jnp.int32(ACCELERATE), params.replace(setpoint_change="tick")
    )
    assert np.isclose(float(per_tick[1].ego.v_setpoint), 2.0 + K * KMH, rtol=1e-3)


def test_a_collision_inside_a_decision_ends_the_episode_at_that_tick():
    """The ego runs into a standing pedestrian a few ticks into a 10-tick decision: the
    decision ends there (terminated, the collision penalty, no further ticks)."""
    params, static = EnvParams(setpoint_change="tick"), StaticEnvParams()
    state, key = _scene(static, params, v=15 * KMH, ped_x=25.0), jax.random.key(4)
    env1 = UrbanPedestrians(static)
    _, _, _, infos = _ticks(env1, key, state, [ACCELERATE] * 10, params, k=10)
    hit = next(i for i, info in enumerate(infos) if info["collision"])
    assert 0 < hit < 9, "the scene must collide inside the decision"
    _, final, total, _ = _ticks(env1, key, state, [ACCELERATE] * (hit + 1), params, k=10)
    envk = UrbanPedestrians(StaticEnvParams(decision_steps=10))
    _, got, r, term, trunc, info = envk.step_env(key, state, jnp.int32(ACCELERATE), params)
    assert term and not trunc and info["collision"]
    assert r == total and r <= params.reward_collision
    assert_tree_equal(got, final)
    assert int(got.time) == int(state.time) + hit + 1
    np.testing.assert_array_equal(info["ticks"]["played"], np.arange(10) <= hit)


def test_truncation_counts_ticks():
    """``max_steps`` is in ticks: with k = 4 and 10 ticks the episode truncates inside
    its third decision, after exactly 10 ticks."""
    envk = UrbanPedestrians(StaticEnvParams(max_steps=10, decision_steps=4))
    params = EnvParams()
    _, state = envk.reset(jax.random.key(0))
    for i in range(3):
        _, state, _, term, trunc, info = envk.step_env(
            jax.random.key(i), state, jnp.int32(STEER), params
        )
    assert trunc and not term and int(state.time) == 10
    np.testing.assert_array_equal(info["ticks"]["played"], [True, True, False, False])


def test_decision_steps_must_be_a_positive_integer():
    with pytest.raises(ValueError, match="decision_steps = 0: must be an integer >= 1"):
        StaticEnvParams(decision_steps=0)
