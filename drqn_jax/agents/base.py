"""The agent interface of every policy: a pytree whose ``params`` are traced leaves and
functions static, so ``jit`` compiles one program per kind of agent, reused for new weights."""

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


@pytree_dataclass(meta_fields=("name", "init_fn", "act_fn", "every_tick"))
class Agent:
    """A policy: ``init_fn(params, key) -> carry`` and ``act_fn(params, key, obs, carry,
    state, env, env_params) -> (() int32 action, carry)``, the true ``state`` read only by
    privileged baselines; ``name`` is for reports. ``every_tick``: it decides at every tick
    of ``dt`` whatever the world's ``decision_steps`` (the yardsticks, SPEC §9)."""

    params: Any
    name: str
    init_fn: InitFn
    act_fn: ActFn
    every_tick: bool = False

    def init_carry(self, key: jax.Array) -> Carry:
        """The policy state at an episode's start (an RNN state, or ``()``)."""
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
