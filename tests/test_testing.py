"""The env-contract checker (drqn_jax/testing.py) passes a correct env and names each broken rule.

A toy env (a walk on the integers, compiled in well under a second) is broken
one rule at a time; each break must make :func:`check_env_contract` fail with
the rule's message. The checker on the drqn_jax worlds is in
``tests/env/test_urban.py``, on a gymnax env in ``tests/learners/test_task.py``.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env import spaces
from drqn_jax.testing import ContractReport, EnvContractError, check_env_contract

MAX_STEPS = 8


class WalkState(NamedTuple):
    x: jax.Array
    time: jax.Array


@dataclasses.dataclass(frozen=True)
class Walk:
    """Actions 0 / 1 step left / right from a random start in {-1, 0, 1}; the
    episode terminates at ``|x| >= goal`` and is truncated after ``MAX_STEPS``
    steps; the reward is ``x / goal``. ``bug`` breaks one rule of the contract."""

    bug: str = ""
    traces: list = dataclasses.field(default_factory=list, compare=False)

    @property
    def default_params(self) -> dict[str, jax.Array]:
        return {"goal": jnp.int32(3)}

    def action_space(self, params=None) -> spaces.Discrete:
        return spaces.Discrete(2)

    def observation_space(self, params=None) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (2,), jnp.float32)

    def _obs(self, state: WalkState, params) -> jax.Array:
        goal = params["goal"].astype(jnp.float32)
        return jnp.stack([state.x / goal, state.time / MAX_STEPS]).astype(jnp.float32)

    def reset(self, key, params=None):
        params = self.default_params if params is None else params
        state = WalkState(jax.random.randint(key, (), -1, 2), jnp.int32(0))
        obs = self._obs(state, params)
        return (10.0 * obs if self.bug == "reset outside" else obs), state

    def step(self, key, state, action, params=None):
        params = self.default_params if params is None else params
        stepped = WalkState(state.x + 2 * action - 1, state.time + 1)
        terminated = jnp.abs(stepped.x) >= params["goal"]
        truncated = (stepped.time >= MAX_STEPS) & ~terminated
        reward = (stepped.x / params["goal"]).astype(jnp.float32)
        final = self._obs(stepped, params)
        reset_key = jax.random.split(key)[1] if self.bug == "gymnax reset key" else key
        fresh_obs, fresh = self.reset(reset_key, params)
        done = terminated | truncated
        state = jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh, stepped)
        # "stale obs": the new episode's state with the old episode's last observation
        obs = jnp.where(done & (self.bug != "stale obs"), fresh_obs, final)
        info = {"final_observation": final + 1.0 if self.bug == "wrong final" else final}
        if self.bug == "nan reward":
            reward = jnp.where(stepped.time == 3, jnp.nan, reward)
        if self.bug == "outside":
            obs = jnp.where(stepped.time == 5, 2.0, obs)
        if self.bug == "float flags":
            terminated = terminated.astype(jnp.float32)
        if self.bug == "obs shape":
            obs = jnp.concatenate([obs, obs])
        if self.bug == "state dtype":
            state = state._replace(x=state.x.astype(jnp.float32))
        if self.bug == "random":  # a value from outside JAX's keys: differs per run
            noise = jax.pure_callback(
                lambda: np.float32(np.random.default_rng().random()),
                jax.ShapeDtypeStruct((), jnp.float32),
            )
            reward = reward + noise
        if self.bug == "traced differently":  # a Python side effect frozen into the jit
            self.traces.append(None)
            reward = reward + len(self.traces)
        return obs, state, reward, terminated, truncated, info


def test_a_correct_env_passes_and_the_report_counts_its_episodes():
    report = check_env_contract(Walk(), num_envs=3, num_steps=20, key=jax.random.key(1))
    assert isinstance(report, ContractReport)
    assert (report.num_envs, report.num_steps) == (3, 20)
    assert report.resets == report.terminations + report.truncations > 0
    assert report.terminations > 0  # a walk reaches |x| = 3 within 20 random steps
    assert -1.0 <= report.reward_min <= report.reward_max <= 1.0


#: Each bug of ``Walk`` and the message the checker must fail with.
BROKEN = {
    "reset outside": r"reset: the observation of env\(s\) \[0 1 2\] is outside the space",
    "outside": r"observation outside observation_space\(params\) at step 4 of env 0",
    "nan reward": r"reward not finite at step 2 of env 0 \(\d+ of 60 steps\)",
    "float flags": r"terminated must be a bool \(\) array; got float32\[\]",
    "obs shape": r"obs: the step returns float32\[4\], the reset float32\[2\]",
    "state dtype": r"state\.x: the step returns float32\[\], the reset int32\[\]",
    "stale obs": r"the episode ended but the returned \(obs, state\) are not reset",
    "gymnax reset key": r"the episode ended but the returned \(obs, state\) are not",
    "wrong final": r"goes on but info\['final_observation'\] is not the returned obs",
    "random": r"the same keys gave a different rollout: \['steps'\]\['reward'\]: values",
    "traced differently": r"jit differs from no jit at step 0: \['reward'\]: values differ",
}


@pytest.mark.parametrize("bug", BROKEN)
def test_each_broken_rule_is_named(bug):
    with pytest.raises(EnvContractError, match=BROKEN[bug]):
        check_env_contract(Walk(bug), num_envs=3, num_steps=20, key=jax.random.key(1))


def test_the_reset_key_is_the_callers_to_choose():
    """gymnax's ``Environment.step`` resets from ``split(key)[1]``, not the step's key."""
    walk = Walk("gymnax reset key")
    report = check_env_contract(walk, num_steps=20, reset_key=lambda k: jax.random.split(k)[1])
    assert report.resets > 0


def test_a_contract_error_is_an_assertion_error_and_sizes_are_checked():
    assert issubclass(EnvContractError, AssertionError)
    for sizes in ({"num_envs": 0}, {"num_steps": 0}, {"num_steps": 2, "eager_steps": 3}):
        with pytest.raises(ValueError, match="num_envs >= 1, num_steps >= 1"):
            check_env_contract(Walk(), **sizes)
