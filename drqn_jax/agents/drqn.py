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
    """Wrap a network and its parameters as a greedy agent (argmax of its outputs:
    Q-values, or PPO's logits); ``name`` defaults to the network kind."""

    def init_fn(params: Any, key: jax.Array) -> Any:
        return network.initial_carry(())

    def act_fn(params, key, obs, carry, state, env, env_params):
        q, carry = network.step(params, obs, carry)
        return jnp.argmax(q).astype(jnp.int32), carry

    name = name or network.config.kind
    return Agent(
        params=params,
        name=name,
        init_fn=_cached(network, name, "init", init_fn),
        act_fn=_cached(network, name, "act", act_fn),
    )


_FUNCTIONS: dict[tuple[Any, str, str], Any] = {}


def _cached(network: Network, name: str, role: str, fn: Any) -> Any:
    """One function object per (network config, agent name, role), so ``jit`` reuses
    its compilation (PPO's policy, :func:`drqn_jax.ppo.policy_network`, is named
    apart from a Q-network of the same config)."""
    return _FUNCTIONS.setdefault((network.config, name, role), fn)
