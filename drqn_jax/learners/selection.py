"""Choosing the run's agent among parameter snapshots (the project's, not the paper's).

With ``snapshots`` = K > 0 the training state keeps the online parameters as
they were when the recorded episodes reached k · num_episodes / (K + 1),
k = 1 … K (:func:`snapshot_thresholds`, :func:`take_snapshot`). After training,
the K candidates and the final parameters each play ``validation_episodes``
greedy episodes of a key of their own (the task's ``validate``), and the run's
agent is the candidate that ``select_by`` prefers (:func:`chosen_candidate`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.evaluation import episode_keys
from drqn_jax.learners.hyperparams import SELECT_BY, Hyperparams, TrainConfig

__all__ = [
    "VALIDATION_METRICS",
    "VALIDATION_STREAM",
    "candidate_metrics",
    "chosen_candidate",
    "run_agent",
    "selection",
    "snapshot_thresholds",
    "take_snapshot",
    "unvalidated",
]

#: What validation measures per candidate of the paper's env, each (K + 1,) float32.
VALIDATION_METRICS = ("return", "collision_free", "speed")
#: ``fold_in`` index of the validation episodes' key (from the finished state's key).
VALIDATION_STREAM = 2
SELECT_SAFE = SELECT_BY.index("safe")


def chosen_candidate(validation: dict[str, jax.Array], hp: Hyperparams) -> jax.Array:
    """() int32 index of the run's agent among its K + 1 candidates, from their
    validation metrics (``VALIDATION_METRICS``, each (K + 1,)):

    * ``select_by = "return"``: the best mean return;
    * ``select_by = "safe"``: among the candidates whose mean speed is at least
      ``select_speed_floor``, the highest collision-free rate, then the best
      return; the final parameters when none is as fast.

    Of equal candidates, the latest. The final parameters (K) while any metric
    is NaN (not validated yet). A task that measures the return alone (a gymnax
    env, :mod:`drqn_jax.learners.task`) has no ``"safe"`` choice: the best return.
    """
    returns = validation["return"]
    last = returns.shape[-1] - 1
    unusable = jnp.any(jnp.isnan(jnp.stack(list(validation.values()))))
    if "speed" not in validation:  # a task that measures returns only: select_by "return"
        return jnp.where(unusable, last, last - jnp.argmax(returns[::-1])).astype(jnp.int32)
    fast = validation["speed"] >= hp.select_speed_floor
    safest = jnp.max(jnp.where(fast, validation["collision_free"], -jnp.inf))
    safe = fast & (validation["collision_free"] == safest)
    score = jnp.where((hp.select_by != SELECT_SAFE) | safe, returns, -jnp.inf)
    best = last - jnp.argmax(score[::-1])
    unusable |= (hp.select_by == SELECT_SAFE) & ~jnp.any(fast)
    return jnp.where(unusable, last, best).astype(jnp.int32)


def selection(validation: dict[str, Any] | None, hp: Hyperparams) -> dict[str, Any]:
    """Host-side record of a run's choice: ``{}`` without snapshots, else each
    candidate's validation metrics (K + 1 floats each, the last the final
    parameters'; NaN before validation) — ``validation_returns``,
    ``validation_collision_free``, ``validation_speed_kmh`` — and ``selected``
    (:func:`chosen_candidate`, K = the final parameters)."""
    if validation is None:
        return {}
    validation = {name: jnp.asarray(v) for name, v in validation.items()}
    out = {"validation_returns": [float(r) for r in validation["return"]]}
    if "collision_free" in validation:
        out["validation_collision_free"] = [float(r) for r in validation["collision_free"]]
        out["validation_speed_kmh"] = [float(v) for v in validation["speed"] * 3.6]
    return {**out, "selected": int(chosen_candidate(validation, hp))}


def unvalidated(snapshots: int, names: tuple[str, ...] = VALIDATION_METRICS) -> dict:
    """``TrainState.validation`` before validation: NaN for each of the
    ``snapshots`` + 1 candidates and each of ``names`` (the task's validation
    metrics; the paper's env: ``VALIDATION_METRICS``)."""
    return {name: jnp.full((snapshots + 1,), jnp.nan, jnp.float32) for name in names}


def snapshot_thresholds(config: TrainConfig) -> tuple[int, ...]:
    """Recorded-episode counts at which snapshots 1 … K are taken:
    ``k · num_episodes // (K + 1)``, at least ``num_envs`` apart."""
    k_plus_1 = config.snapshots + 1
    return tuple(k * config.num_episodes // k_plus_1 for k in range(1, k_plus_1))


def take_snapshot(
    config: TrainConfig, snapshots: Any, online: Any, before: jax.Array, after: jax.Array
) -> Any:
    """``snapshots`` (leaves [K, ...]) with ``online`` written to slot k when the
    recorded episodes cross threshold k between ``before`` and ``after`` (at
    most one: they are ``num_envs`` apart); unchanged when K = 0.

    One slot is read and written whether or not it changes, so the cost does
    not grow with K and stays small under ``vmap`` (a ``cond`` would become a
    select of the whole stack).
    """
    if not config.snapshots:
        return snapshots
    thresholds = jnp.asarray(snapshot_thresholds(config), jnp.int32)
    crossed_before = jnp.sum(thresholds <= before)
    crossed = jnp.sum(thresholds <= after)
    slot = jnp.maximum(crossed - 1, 0)
    write = crossed > crossed_before
    return jax.tree.map(
        lambda s, o: s.at[slot].set(jnp.where(write, o, s[slot])), snapshots, online
    )


def candidates(snapshots: Any, online: Any) -> Any:
    """The K snapshots and the final online parameters, stacked: leaves [K + 1, ...]."""
    return jax.tree.map(lambda s, o: jnp.concatenate([s, o[None]]), snapshots, online)


def candidate_metrics(config: TrainConfig, task: Any, network: Any, state: Any) -> dict:
    """The task's validation metrics of a finished run's candidates, each (K + 1,)
    float32 — for the paper's env ``VALIDATION_METRICS``: every candidate's mean
    greedy return, share of collision-free episodes and mean speed (m/s, the mean
    over episodes of distance / time, SPEC §8); for a gymnax env the mean greedy
    return — over ``validation_episodes`` episodes of ``fold_in(state.key,
    VALIDATION_STREAM)`` (the same episodes for every candidate). Needs K > 0."""
    if not config.snapshots:
        raise ValueError("validation_metrics: the run keeps no snapshots (train.snapshots = 0)")
    keys = episode_keys(
        jax.random.fold_in(state.key, VALIDATION_STREAM), config.validation_episodes
    )

    def measure(params: Any) -> dict[str, jax.Array]:
        return task.validate(network, params, keys, state.env_params)

    return jax.lax.map(measure, candidates(state.snapshots, state.online))


def run_agent(config: TrainConfig, state: Any) -> Any:
    """The run's agent: the final online parameters, or with K > 0 and
    ``state.validation`` filled in, the candidate that ``select_by`` prefers
    (:func:`chosen_candidate`)."""
    if not config.snapshots:
        return state.online
    best = chosen_candidate(state.validation, state.hparams)
    return jax.tree.map(lambda c: c[best], candidates(state.snapshots, state.online))
