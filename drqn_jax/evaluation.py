"""Evaluation over many episodes (paper §V-E, Table III; SPEC §8): :func:`run_episodes` under
one ``jit``, :func:`summarize` to the §8 metrics, :func:`evaluate` both. Episode *i* uses
``fold_in(key, i)``, whatever episodes run beside it."""

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.agents.base import Agent
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.programs import jit_in_store
from drqn_jax.pytree import pytree_dataclass

Z_95 = 1.959963984540054  # two-sided 95 % normal quantile

#: Rows of every batch of episodes (:func:`padded_keys` pads to a multiple of it).
#: XLA:CPU rounds the same episode differently with the rows beside it (YNNPACK's matrix
#: kernels below 61–81 rows, another switch near 470 rows), so every program of episodes
#: runs exactly this many: episode i has the same bits whatever N or the caller.
EVAL_BATCH = 512

#: m/s: the authors' average speed counts the steps faster than 0.5 km/h (``tester.py``).
AUTHORS_MOVING_SPEED = 0.5 * KMH


@pytree_dataclass
class EpisodeMetrics:
    """What one episode produced; every leaf gains a leading axis when batched."""

    episode_return: jax.Array  # () float32, sum of rewards
    length: jax.Array  # () int32, steps played
    collision: jax.Array  # () bool
    goal: jax.Array  # () bool, route end reached
    distance: jax.Array  # () float32, metres along the route
    mean_speed: jax.Array  # () float32, distance / duration
    min_ttc: jax.Array  # () float32, smallest TTC (s, inf if never finite)
    near_collision_steps: jax.Array  # () int32, steps with TTC <= ttc_threshold
    # () bool, a pedestrian met the collision test while the ego stood (SPEC §5: no collision)
    struck_while_stopped: jax.Array
    moving_steps: jax.Array  # () int32, steps with v > AUTHORS_MOVING_SPEED
    # () float32, mean speed over the moving steps (carla-gym tester.py; m/s, 0 if none)
    authors_speed: jax.Array


def episode_keys(key: jax.Array, num_episodes: int, offset: int = 0) -> jax.Array:
    """(N,) keys ``fold_in(key, offset + i)``: episode i's key does not depend on N."""
    idx = jnp.arange(offset, offset + num_episodes, dtype=jnp.uint32)
    return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, idx)


class Decision(NamedTuple):
    """One decision of an episode, as :func:`play_episode` hands it to ``trace``: the
    Observation and EnvState the action was chosen on, the agent's carry after choosing,
    () int32 ``action``, () float32 ``reward``, () bool flags, ``step_env``'s info."""

    obs: Any
    state: Any
    carry: Any
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    info: dict[str, jax.Array]


def _no_metrics() -> EpisodeMetrics:
    zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)
    false = jnp.zeros((), bool)
    return EpisodeMetrics(
        episode_return=zero_f,
        length=zero_i,
        collision=false,
        goal=false,
        distance=zero_f,
        mean_speed=zero_f,
        min_ttc=jnp.asarray(jnp.inf, jnp.float32),
        near_collision_steps=zero_i,
        struck_while_stopped=false,
        moving_steps=zero_i,
        authors_speed=zero_f,  # the sum of the moving steps' speeds until the end
    )


def _accumulate(
    m: EpisodeMetrics, live: jax.Array, reward: jax.Array, info: dict, params: EnvParams
) -> EpisodeMetrics:
    """``m`` after one more decision; one after the episode ended (``~live``) counts
    nothing. Lengths, speeds and TTC count ticks of ``dt`` (SPEC §8): a k-tick decision
    (``info["ticks"]``, leaves (k,)) counts each tick it played."""
    m = m.replace(episode_return=m.episode_return + jnp.where(live, reward, 0.0))
    ticks = info.get("ticks")
    for i in range(1 if ticks is None else ticks["played"].shape[0]):
        tick = info if ticks is None else jax.tree.map(lambda x, i=i: x[i], ticks)
        played = live if ticks is None else live & tick["played"]
        ttc = tick["ttc"]
        moving = played & (tick["speed"] > AUTHORS_MOVING_SPEED)
        m = m.replace(
            length=m.length + played.astype(jnp.int32),
            collision=m.collision | (played & tick["collision"]),
            goal=m.goal | (played & tick["goal"]),
            distance=jnp.where(played, tick["distance"], m.distance),
            min_ttc=jnp.where(played, jnp.minimum(m.min_ttc, ttc), m.min_ttc),
            near_collision_steps=m.near_collision_steps
            + (played & (ttc <= params.ttc_threshold)).astype(jnp.int32),
            struck_while_stopped=m.struck_while_stopped | (played & tick["struck_while_stopped"]),
            moving_steps=m.moving_steps + moving.astype(jnp.int32),
            authors_speed=m.authors_speed + jnp.where(moving, tick["speed"], 0.0),
        )
    return m


def play_episode(
    agent: Agent,
    key: jax.Array,
    env: UrbanPedestrians,
    params: EnvParams,
    trace: Callable[[Decision], Any] | None = None,
) -> tuple[EpisodeMetrics, Any, Any, Any]:
    """Play and measure one episode, the one rollout of evaluation and recording: T =
    ceil(max_steps / decision_steps) decisions, branch-free (those after the end count
    nothing; an ``every_tick`` agent decides every tick). Returns ``(metrics, traced, obs,
    state)``: ``trace`` per :class:`Decision` (leaves (T, ...) or None), then the last obs/state."""
    if agent.every_tick and env.static.decision_steps > 1:
        env = dataclasses.replace(env, static=dataclasses.replace(env.static, decision_steps=1))
    key_reset, key_carry, key_run = jax.random.split(key, 3)
    obs, state = env.reset_env(key_reset, params)

    def step(loop, step_key):
        obs, state, carry, m, done = loop
        key_act, key_env = jax.random.split(step_key)
        action, carry = agent.act(key_act, obs, carry, state, env, params)
        next_obs, next_state, reward, terminated, truncated, info = env.step_env(
            key_env, state, action, params
        )
        decision = Decision(obs, state, carry, action, reward, terminated, truncated, info)
        traced = None if trace is None else trace(decision)
        m = _accumulate(m, ~done, reward, info, params)
        return (next_obs, next_state, carry, m, done | terminated | truncated), traced

    init = (obs, state, agent.init_carry(key_carry), _no_metrics(), jnp.zeros((), bool))
    decisions = -(-env.static.max_steps // env.static.decision_steps)  # ticks <= max_steps
    (obs, state, _, m, _), traced = jax.lax.scan(step, init, jax.random.split(key_run, decisions))
    duration = jnp.maximum(m.length, 1).astype(jnp.float32) * params.dt
    authors = m.authors_speed / jnp.maximum(m.moving_steps, 1).astype(jnp.float32)
    m = m.replace(
        mean_speed=(m.distance / duration).astype(jnp.float32),
        authors_speed=authors.astype(jnp.float32),
    )
    return m, traced, obs, state


def run_episodes(
    agent: Agent, keys: jax.Array, env: UrbanPedestrians, params: EnvParams
) -> EpisodeMetrics:
    """EpisodeMetrics (N, ...) of one episode per key (N,), under one ``jit``, in batches of
    :data:`EVAL_BATCH` (the keys padded by :func:`padded_keys`, the padding dropped)."""
    n = keys.shape[0]
    out = _run_padded(agent, padded_keys(keys), env, params)
    return jax.tree.map(lambda x: x[:n], out)


def rollouts(
    agent: Agent, keys: jax.Array, env: UrbanPedestrians, params: EnvParams
) -> EpisodeMetrics:
    """:func:`map_episodes` of :func:`play_episode`'s metrics, not jitted."""
    return map_episodes(lambda key: play_episode(agent, key, env, params)[0], keys)


_run_padded = jit_in_store("env")(rollouts)


def padded_keys(keys: jax.Array) -> jax.Array:
    """``keys`` (N,) and copies of its first key, to a multiple of :data:`EVAL_BATCH`."""
    n = keys.shape[0]
    fill = jnp.broadcast_to(keys[:1], (-n % EVAL_BATCH, *keys.shape[1:]))
    return jnp.concatenate([keys, fill])


def map_episodes(fn: Any, keys: jax.Array) -> Any:
    """``vmap(fn)(keys)`` in batches of exactly :data:`EVAL_BATCH` rows (the keys padded,
    the padding dropped), so that episode i has the same bits whatever the episodes beside
    it."""
    n = keys.shape[0]
    keys = padded_keys(keys)
    if keys.shape[0] == EVAL_BATCH:
        out = jax.vmap(fn)(keys)
    else:
        out = jax.lax.map(fn, keys, batch_size=EVAL_BATCH)
    return jax.tree.map(lambda x: x[:n], out)


def wilson_interval(successes: int, trials: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion (95 % by default)."""
    if trials <= 0:
        return (0.0, 1.0)
    p = successes / trials
    denom = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z / denom * math.sqrt(p * (1.0 - p) / trials + z * z / (4.0 * trials * trials))
    # At p = 0 or 1 one end is exactly 0 or 1; keep rounding from moving it.
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == trials else min(1.0, centre + half)
    return (low, high)


def _mean(values: np.ndarray) -> float:
    return float(values.mean()) if values.size else math.nan


def summarize_outcomes(episodes: EpisodeMetrics) -> dict[str, Any]:
    """:func:`summarize` but its ``min_ttc_*`` and ``near_collision_*`` keys, for a sweep
    that drops the TTC from its program (:mod:`drqn_jax.experiments.frontier`)."""
    ep = jax.tree.map(np.asarray, episodes)
    n = int(ep.collision.shape[0])
    collided = ep.collision.astype(bool)
    free = ~collided
    distance = ep.distance.astype(np.float64)
    total_km = distance.sum() / 1000.0
    moving = ep.moving_steps.astype(np.float64)
    moving_speed_sum = float((ep.authors_speed.astype(np.float64) * moving).sum())
    return {
        "num_episodes": n,
        "collision_free_rate": _mean(free),
        "collision_free_ci": wilson_interval(int(free.sum()), n),
        "goal_rate": _mean(ep.goal),
        "struck_while_stopped_rate": _mean(ep.struck_while_stopped),
        "avg_speed_kmh": _mean(ep.mean_speed.astype(np.float64)) * 3.6,
        "avg_speed_authors_kmh": (
            moving_speed_sum / moving.sum() * 3.6 if moving.sum() > 0 else math.nan
        ),
        "avg_distance_m": _mean(distance),
        "avg_distance_collision_free_m": _mean(distance[free]),
        "collisions_per_km": float(collided.sum() / total_km) if total_km > 0 else math.nan,
        "avg_return": _mean(ep.episode_return.astype(np.float64)),
        "avg_length": _mean(ep.length.astype(np.float64)),
    }


def summarize(episodes: EpisodeMetrics, ttc_threshold: float = 3.0) -> dict[str, Any]:
    """The §8 metrics of per-episode results as Python floats: ``collision_free_ci`` the 95 %
    Wilson interval; ``avg_speed_authors_kmh`` over steps faster than 0.5 km/h, pooled
    (carla-gym ``tester.py``); ``near_collision_episode_rate``: min TTC <= ``ttc_threshold``."""
    ep = jax.tree.map(np.asarray, episodes)
    min_ttc = ep.min_ttc.astype(np.float64)

    def quantile(q: float) -> float:
        return float(np.quantile(min_ttc, q, method="nearest")) if min_ttc.size else math.nan

    return {
        **summarize_outcomes(ep),
        "min_ttc_p05_s": quantile(0.05),
        "min_ttc_median_s": quantile(0.5),
        "min_ttc_mean_finite_s": _mean(min_ttc[np.isfinite(min_ttc)]),
        "near_collision_episode_rate": _mean(min_ttc <= ttc_threshold),
        "near_collision_step_share": float(
            ep.near_collision_steps.sum() / max(ep.length.astype(np.float64).sum(), 1.0)
        ),
    }


def evaluate(
    agent: Agent,
    key: jax.Array,
    num_episodes: int,
    env: UrbanPedestrians,
    params: EnvParams | None = None,
    *,
    on_episodes: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Evaluate ``agent`` on ``num_episodes`` episodes (SPEC §8) in calls of :data:`EVAL_BATCH`
    (one program, the last padded), ``on_episodes(done)`` after each: :func:`summarize`'s
    dict plus ``agent`` and ``episodes`` (:class:`EpisodeMetrics`, NumPy leaves (N, ...))."""
    if not isinstance(num_episodes, int) or num_episodes < 1:
        raise ValueError(f"evaluate: num_episodes = {num_episodes!r}, must be an integer >= 1")
    params = env.default_params if params is None else env.check_params(params)
    keys = episode_keys(key, num_episodes)
    parts = []
    for start in range(0, num_episodes, EVAL_BATCH):
        real = min(EVAL_BATCH, num_episodes - start)
        out = run_episodes(agent, keys[start : start + real], env, params)
        parts.append(jax.tree.map(np.asarray, out))
        if on_episodes is not None:
            on_episodes(start + real)
    episodes = jax.tree.map(lambda *xs: np.concatenate(xs), *parts)
    result = summarize(episodes, float(np.asarray(params.ttc_threshold)))
    return {"agent": agent.name, **result, "episodes": episodes}


def metrics_table(results: list[dict[str, Any]]) -> str:
    """A Markdown table of :func:`evaluate` results, one row per agent (SPEC §8), with
    the ``teacher`` that :func:`drqn_jax.experiments.runner.evaluate_agents` adds."""
    header = (
        "| agent | teacher | episodes | collision-free % (95 % CI) | struck while stopped % "
        "| goal % | avg speed (km/h) | authors' speed (km/h) | distance (m) "
        "| distance, collision-free (m) | collisions / km | min TTC median (s) "
        "| steps with TTC ≤ 3 s % |"
    )
    rows = [header, "| " + " | ".join(["---"] * (header.count("|") - 1)) + " |"]
    for r in results:
        low, high = r["collision_free_ci"]
        rows.append(
            f"| {r['agent']} | {r.get('teacher', '–')} | {r['num_episodes']} "
            f"| {100 * r['collision_free_rate']:.1f} ({100 * low:.1f}–{100 * high:.1f}) "
            f"| {100 * r['struck_while_stopped_rate']:.1f} | {100 * r['goal_rate']:.1f} "
            f"| {r['avg_speed_kmh']:.2f} | {r['avg_speed_authors_kmh']:.2f} "
            f"| {r['avg_distance_m']:.1f} | {r['avg_distance_collision_free_m']:.1f} "
            f"| {r['collisions_per_km']:.3f} | {r['min_ttc_median_s']:.1f} "
            f"| {100 * r['near_collision_step_share']:.2f} |"
        )
    return "\n".join(rows)
