"""The registered worlds: no standoffs in any, and the paper's world as calibrated (SPEC §3, §5)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax
from drqn_jax.agents.rule_based import RuleBasedParams, must_brake, rule_based_action
from drqn_jax.env.grid import GridInputs
from drqn_jax.env.params import EnvParams
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.registry import registered_envs

EPISODES = 256
STANDOFF_S = 20.0  # the ego standing this long for a standing pedestrian is a standoff


@functools.partial(jax.jit, static_argnames="env")
def longest_standoffs(
    keys: jax.Array, env: UrbanPedestrians, params: EnvParams, rb: RuleBasedParams
) -> jax.Array:
    """(N,) int32: per rule-based episode, the longest run of steps in which the
    ego stands still while a standing pedestrian whose path is unfinished is in
    its braking corridor (the rule-based agent's: SPEC §6)."""

    def episode(key):
        key_reset, key_run = jax.random.split(key)
        _, state = env.reset_env(key_reset, params)

        def step(carry, step_key):
            state, run, longest, done = carry
            action = rule_based_action(state, params, rb, env.static)
            _, state, _, terminated, truncated, _ = env.step_env(step_key, state, action, params)
            peds = state.pedestrians
            standing = (peds.speed == 0.0) & ~peds.done
            # Only the standing pedestrians count: move the others out of every corridor.
            position = jnp.where(standing[:, None], peds.position, 1e6)
            g = GridInputs.of(state.ego.replace(v=0.0), peds.replace(position=position))
            held = must_brake(g, params, rb, env.static)
            stuck = ~done & (state.ego.v < params.stopped_speed) & held
            run = jnp.where(stuck, run + 1, 0)
            longest = jnp.maximum(longest, run)
            return (state, run, longest, done | terminated | truncated), None

        zero = jnp.zeros((), jnp.int32)
        carry = (state, zero, zero, jnp.zeros((), bool))
        keys = jax.random.split(key_run, env.static.max_steps)
        (_, _, longest, _), _ = jax.lax.scan(step, carry, keys)
        return longest

    return jax.vmap(episode)(keys)


def standoff_count(params: EnvParams) -> int:
    env = UrbanPedestrians()
    keys = jax.random.split(jax.random.key(0), EPISODES)
    longest = np.asarray(longest_standoffs(keys, env, params, RuleBasedParams()))
    return int(np.sum(longest * float(params.dt) >= STANDOFF_S))


@pytest.mark.parametrize("env_id", registered_envs())
def test_no_standoff_in_any_registered_world(env_id):
    """SPEC §3: a yielding pedestrian waits at most ped_wait_max_s, then walks on, so no
    rule-based episode has the ego stand 20 s for a pedestrian standing in its corridor."""
    _, params = drqn_jax.make(env_id)
    assert standoff_count(params) == 0


def test_the_standoff_check_finds_pedestrians_that_wait_for_ever():
    """The check can fail: with no timeout a pedestrian
    and the braking ego wait for each other for ever in a share of the episodes."""
    _, params = drqn_jax.make("UrbanPedestriansYielding-v0", ped_wait_max_s=1000.0)
    assert standoff_count(params) >= EPISODES // 20


def test_paper_world_is_the_default():
    """SPEC §3, §5: pedestrians ignore the car and the authors' collision test; the
    yielding world keeps its contact test and the 5 s timeout."""
    _, default = drqn_jax.make()
    _, paper = drqn_jax.make("UrbanPedestrians-v0")
    assert int(default.ped_behaviour_to_car) == int(paper.ped_behaviour_to_car) == 0  # ignore
    assert int(default.collision_model) == 1  # authors
    _, yielding = drqn_jax.make("UrbanPedestriansYielding-v0")
    assert int(yielding.ped_behaviour_to_car) == 1 and int(yielding.collision_model) == 0
    assert float(yielding.ped_wait_max_s) == 5.0
