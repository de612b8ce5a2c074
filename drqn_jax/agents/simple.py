"""Reference policies: uniform random and constant action."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import Agent, no_carry
from drqn_jax.env.state import ACCELERATE, ACTIONS, NUM_ACTIONS

__all__ = ["constant_agent", "random_agent"]


def _random_act(params, key, obs, carry, state, env, env_params):
    return jax.random.randint(key, (), 0, NUM_ACTIONS, dtype=jnp.int32), carry


def _constant_act(params, key, obs, carry, state, env, env_params):
    return jnp.asarray(params, jnp.int32), carry


def random_agent() -> Agent:
    """Uniform over the four actions."""
    return Agent(params=(), name="random", init_fn=no_carry, act_fn=_random_act)


def constant_agent(action: int = ACCELERATE) -> Agent:
    """Always the same action (``ACCELERATE`` by default: "always-accelerate")."""
    action = ACTIONS.index(action) if action in ACTIONS else action
    if not isinstance(action, int) or not 0 <= action < NUM_ACTIONS:
        raise ValueError(
            f"constant_agent: action = {action!r}, allowed 0 <= action < {NUM_ACTIONS} "
            f"or one of {ACTIONS}"
        )
    return Agent(
        params=jnp.asarray(action, jnp.int32),
        name=f"always-{ACTIONS[action].replace('_', '-')}",
        init_fn=no_carry,
        act_fn=_constant_act,
    )
