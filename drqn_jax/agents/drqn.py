"""The trained (D)RQN as an :class:`~drqn_jax.agents.base.Agent` (paper §V-E; SPEC §8).

Greedy (ε = 0): the action is ``argmax Q`` of the network's step on the
observation; the LSTM carry is threaded through the episode and starts from
zeros.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import Agent
from drqn_jax.networks import Network

__all__ = ["drqn_agent"]


def drqn_agent(network: Network, params: Any, name: str | None = None) -> Agent:
    """Wrap a network and its parameters as a greedy agent."""

    def init_fn(params: Any, key: jax.Array) -> Any:
        return network.initial_carry(())

    def act_fn(params, key, obs, carry, state, env, env_params):
        q, carry = network.step(params, obs, carry)
        return jnp.argmax(q).astype(jnp.int32), carry

    return Agent(
        params=params,
        name=name or network.config.kind,
        init_fn=_cached(network, "init", init_fn),
        act_fn=_cached(network, "act", act_fn),
    )


_FUNCTIONS: dict[tuple[Any, str], Any] = {}


def _cached(network: Network, role: str, fn: Any) -> Any:
    """One function object per (network config, role), so ``jit`` reuses its compilation."""
    return _FUNCTIONS.setdefault((network.config, role), fn)
