"""The agent interface of every policy: a pytree whose ``params`` are traced leaves and
functions static, so ``jit`` compiles one program per kind of agent, reused for new weights;
and the policies without rules of their own: uniform random, a constant action, and the
trained network's greedy policy (paper §V-E; SPEC §8)."""

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.env.params import EnvParams
from drqn_jax.env.state import ACCELERATE, ACTIONS, NUM_ACTIONS, EnvState, Observation
from drqn_jax.networks import Network
from drqn_jax.programs import cached_program
from drqn_jax.pytree import pytree_dataclass

Carry = Any
InitFn = Callable[[Any, jax.Array], Carry]
ActFn = Callable[
    [Any, jax.Array, Observation, Carry, EnvState, Any, EnvParams], tuple[jax.Array, Carry]
]


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


def drqn_agent(network: Network, params: Any, name: str | None = None) -> Agent:
    """A greedy agent (argmax of Q-values or PPO's logits, the carry threaded from zeros);
    ``name``: the network kind."""
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
