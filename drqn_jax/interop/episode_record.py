"""Recorded episodes (paper §V-E; SPEC §8): episode i is :func:`drqn_jax.evaluate`'s i."""

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.agents.base import ActFn, Agent, InitFn
from drqn_jax.env.collision import ego_box
from drqn_jax.env.params import EnvParams
from drqn_jax.env.state import ACTIONS, EnvState
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.evaluation import Decision, episode_keys, map_episodes, padded_keys, play_episode
from drqn_jax.networks import Network
from drqn_jax.programs import cached_program, jit_in_store
from drqn_jax.pytree import pytree_dataclass


@pytree_dataclass
class EpisodeRecord:
    """N episodes, T = ``max_steps``: state t is before decision t, step t goes from state
    t to t + 1; only ``[:L + 1]`` states and ``[:L]`` steps count, L = ``length[i]``."""

    state: EnvState  # leaves (N, T + 1, ...)
    grid: Any  # (N, T + 1, rows, cols, 4) float32
    ego_centre: Any  # (N, T + 1, 2) float32 (m)
    ego_half: Any  # (N, 2) float32 (m)
    action: Any  # (N, T) int32
    q_values: Any  # (N, T, 4) float32, or None without a network
    reward: Any  # (N, T) float32
    ttc: Any  # (N, T) float32 (s, inf: none)
    collision: Any  # (N, T) bool, like the three below
    struck_while_stopped: Any
    goal: Any
    truncated: Any
    length: Any  # (N,) int32
    episode_return: Any  # (N,) float32

    @property
    def num_episodes(self) -> int:
        return int(np.shape(self.length)[0])

    def outcome(self, i: int) -> str:
        """How episode ``i`` ended: ``"collision"``, ``"goal"`` or ``"truncated"``."""
        n = int(self.length[i])
        if n and self.collision[i, n - 1]:
            return "collision"
        return "goal" if n and self.goal[i, n - 1] else "truncated"


def _stack_last(seq: Any, last: Any) -> Any:
    """Leaves (T, ...) and (...) -> (T + 1, ...)."""
    return jax.tree.map(lambda s, x: jnp.concatenate([s, x[None]], axis=0), seq, last)


@cached_program
def _q_values_beside(init_fn: InitFn, act_fn: ActFn, network: Network) -> tuple[InitFn, ActFn]:
    """An agent's functions with ``network`` beside it: carry ``(agent carry, network
    carry, Q (4,))``, params ``(agent params, network params)``."""

    def init(params: Any, key: jax.Array) -> Any:
        inner, _ = params
        q = jnp.zeros((len(ACTIONS),), jnp.float32)
        return init_fn(inner, key), network.initial_carry(()), q

    def act(params: Any, key: jax.Array, obs: Any, carry: Any, *rest: Any) -> Any:
        (inner, net), (inner_carry, q_carry, _) = params, carry
        action, inner_carry = act_fn(inner, key, obs, inner_carry, *rest)
        q, q_carry = network.step(net, obs, q_carry)
        return action, (inner_carry, q_carry, q)

    return init, act


_STEP_FIELDS = ("reward", "truncated", "ttc", "collision", "struck_while_stopped", "goal")


def _record_decision(d: Decision) -> dict[str, Any]:
    out = {"state": d.state, "grid": d.obs.grid, "reward": d.reward, "truncated": d.truncated}
    return out | {k: d.info[k] for k in _STEP_FIELDS[2:]}


@jit_in_store("env", "with_q")
def _decisions(
    agent: Agent, keys: jax.Array, env: UrbanPedestrians, params: EnvParams, with_q: bool
) -> tuple[jax.Array, Any]:
    """Actions (N, T) and, ``with_q``, Q (N, T, 4) from the evaluation's own rollout."""

    def decision(d: Decision) -> tuple[jax.Array, Any]:
        return d.action, d.carry[2] if with_q else None

    def one(key: jax.Array) -> tuple[jax.Array, Any]:
        return play_episode(agent, key, env, params, decision)[1]

    return map_episodes(one, keys)


def _first_decision(actions: jax.Array, key: jax.Array) -> jax.Array:
    return jnp.zeros((), jnp.int32)


def _next_action(actions: jax.Array, key: jax.Array, obs: Any, t: jax.Array, *rest: Any) -> Any:
    return actions[t], t + 1


@jit_in_store("env")
def _rollouts(
    actions: jax.Array, keys: jax.Array, env: UrbanPedestrians, params: EnvParams
) -> EpisodeRecord:
    """``actions`` (N, T) replayed in one episode per key, every state traced."""

    def one(actions: jax.Array, key: jax.Array) -> EpisodeRecord:
        replay = Agent(params=actions, name="replay", init_fn=_first_decision, act_fn=_next_action)
        metrics, out, obs, state = play_episode(replay, key, env, params, _record_decision)
        states = _stack_last(out["state"], state)
        centre, half = ego_box(states.ego.s, params)
        return EpisodeRecord(
            state=states,
            grid=_stack_last(out["grid"], obs.grid),
            ego_centre=centre,
            ego_half=half,
            action=actions,
            q_values=None,
            length=metrics.length,
            episode_return=metrics.episode_return,
            **{k: out[k] for k in _STEP_FIELDS},
        )

    return jax.vmap(one)(actions, keys)


def collect_episodes(
    agent: Agent,
    key: jax.Array,
    num_episodes: int,
    env: UrbanPedestrians,
    env_params: EnvParams | None = None,
    *,
    network: Network | None = None,
    network_params: Any = None,
) -> EpisodeRecord:
    """:class:`EpisodeRecord` (NumPy): played as the evaluation plays, then replayed with
    every state traced (21.6 MB per episode at T = 1000); ``network`` adds Q-values."""
    if not isinstance(num_episodes, int) or num_episodes < 1:
        raise ValueError(f"num_episodes = {num_episodes!r}, must be an integer >= 1")
    if (network is None) != (network_params is None):
        raise ValueError("network and network_params go together (both or neither)")
    env_params = env.default_params if env_params is None else env.check_params(env_params)
    keys = episode_keys(key, num_episodes)
    if network is not None:
        init, act = _q_values_beside(agent.init_fn, agent.act_fn, network)
        agent = Agent(
            params=(agent.params, network_params), name=agent.name, init_fn=init, act_fn=act
        )
    decided = _decisions(agent, padded_keys(keys), env, env_params, network is not None)
    actions, q_values = jax.tree.map(lambda x: x[:num_episodes], decided)
    record = _rollouts(actions, keys, env, env_params).replace(q_values=q_values)
    return jax.tree.map(np.asarray, record)
