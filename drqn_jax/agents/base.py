"""The agent interface shared by the rule-based baseline, simple policies and the DRQN.

An :class:`Agent` is a pytree: its ``params`` (network weights, thresholds…)
are traced leaves, its functions are static. So ``jit`` compiles one program
per kind of agent and reuses it for new weights, and an agent can be passed
straight into ``jit``/``vmap``-ed code.

* ``init_carry(key) -> carry``: the per-episode policy state (an LSTM state
  for the DRQN, ``()`` for memoryless policies);
* ``act(key, obs, carry, state, env, env_params) -> (action, carry)``: one
  action () int32 for one environment. ``state`` is the true simulator
  state, which privileged baselines (the rule-based agent, paper §V-E) read
  and learned agents ignore.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax

from drqn_jax.env.params import EnvParams
from drqn_jax.env.state import EnvState, Observation
from drqn_jax.pytree import pytree_dataclass

Carry = Any
InitFn = Callable[[Any, jax.Array], Carry]
ActFn = Callable[
    [Any, jax.Array, Observation, Carry, EnvState, Any, EnvParams], tuple[jax.Array, Carry]
]

__all__ = ["ActFn", "Agent", "Carry", "InitFn", "no_carry"]


def no_carry(params: Any, key: jax.Array) -> tuple[()]:
    """``init_fn`` of a memoryless policy."""
    return ()


@pytree_dataclass(meta_fields=("name", "init_fn", "act_fn"))
class Agent:
    """A policy behind one interface (see the module docstring).

    Attributes:
        params: traced pytree of the policy's parameters.
        name: a short name for reports.
        init_fn: ``(params, key) -> carry``.
        act_fn: ``(params, key, obs, carry, state, env, env_params) -> (action, carry)``.
    """

    params: Any
    name: str
    init_fn: InitFn
    act_fn: ActFn

    def init_carry(self, key: jax.Array) -> Carry:
        """The policy state at the start of an episode."""
        return self.init_fn(self.params, key)

    def act(
        self,
        key: jax.Array,
        obs: Observation,
        carry: Carry,
        state: EnvState,
        env: Any,
        env_params: EnvParams,
    ) -> tuple[jax.Array, Carry]:
        """One action for one environment, and the next carry."""
        return self.act_fn(self.params, key, obs, carry, state, env, env_params)
