"""The trained network as a greedy :class:`~drqn_jax.agents.base.Agent` (paper §V-E;
SPEC §8): ``argmax`` of its step, the carry threaded from zeros.
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
    """A greedy agent (argmax of Q-values or PPO's logits); ``name``: the network kind."""
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
