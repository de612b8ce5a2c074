"""The trained (D)RQN as an :class:`~drqn_jax.agents.base.Agent` (paper §V-E; SPEC §8).

Greedy (ε = 0): the action is ``argmax Q`` of the network's step on the
observation; the LSTM carry is threaded through the episode and starts from
zeros.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import ActFn, Agent, InitFn
from drqn_jax.networks import Network
from drqn_jax.programs import cached_program

__all__ = ["drqn_agent"]


def drqn_agent(network: Network, params: Any, name: str | None = None) -> Agent:
    """Wrap a network and its parameters as a greedy agent (argmax of its outputs:
    Q-values, or PPO's logits); ``name`` defaults to the network kind."""

    name = name or network.config.kind
    init_fn, act_fn = _greedy_functions(network)
    return Agent(params=params, name=name, init_fn=init_fn, act_fn=act_fn)


@cached_program
def _greedy_functions(network: Network) -> tuple[InitFn, ActFn]:
    """One ``(init_fn, act_fn)`` per network, so ``jit`` reuses its compilation."""

    def init_fn(params: Any, key: jax.Array) -> Any:
        return network.initial_carry(())

    def act_fn(params, key, obs, carry, state, env, env_params):
        q, carry = network.step(params, obs, carry)
        return jnp.argmax(q).astype(jnp.int32), carry

    return init_fn, act_fn
