"""Choosing the run's agent among parameter snapshots (the project's, not the paper's).

With ``snapshots`` = K > 0 the online parameters are kept at k · num_episodes / (K + 1)
recorded episodes; the K and the final ones play greedy validation episodes, and
``select_by`` picks the agent.
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
    """() int32 index of the run's agent among K + 1 candidates (metrics (K + 1,)):
    the best return, or with ``"safe"`` the most collision-free at
    ``select_speed_floor`` or faster, then the best return. Ties: the latest; any
    NaN, or none fast enough: the final parameters (K).
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
    """Host-side record of a run's choice: ``{}`` without snapshots, else the
    candidates' ``validation_*`` lists (K + 1 floats) and ``selected``."""
    if validation is None:
        return {}
    validation = {name: jnp.asarray(v) for name, v in validation.items()}
    out = {"validation_returns": [float(r) for r in validation["return"]]}
    if "collision_free" in validation:
        out["validation_collision_free"] = [float(r) for r in validation["collision_free"]]
        out["validation_speed_kmh"] = [float(v) for v in validation["speed"] * 3.6]
    return {**out, "selected": int(chosen_candidate(validation, hp))}


def unvalidated(snapshots: int, names: tuple[str, ...] = VALIDATION_METRICS) -> dict:
    """``TrainState.validation`` before validation: NaN (snapshots + 1,) per name."""
    return {name: jnp.full((snapshots + 1,), jnp.nan, jnp.float32) for name in names}


def snapshot_thresholds(config: TrainConfig) -> tuple[int, ...]:
    """Recorded-episode counts at which snapshots 1 … K are taken:
    ``k · num_episodes // (K + 1)``, at least ``num_envs`` apart."""
    k_plus_1 = config.snapshots + 1
    return tuple(k * config.num_episodes // k_plus_1 for k in range(1, k_plus_1))


def take_snapshot(
    config: TrainConfig, snapshots: Any, online: Any, before: jax.Array, after: jax.Array
) -> Any:
    """``snapshots`` (leaves [K, ...]) with ``online`` in slot k when the recorded
    episodes cross threshold k between ``before`` and ``after``. One slot is always
    rewritten, so the cost under ``vmap`` does not grow with K."""
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
    """The task's validation metrics (K + 1,) float32 of a finished run's candidates,
    on the same ``validation_episodes`` for each (SPEC §8). Needs K > 0."""
    if not config.snapshots:
        raise ValueError("validation_metrics: the run keeps no snapshots (train.snapshots = 0)")
    keys = episode_keys(
        jax.random.fold_in(state.key, VALIDATION_STREAM), config.validation_episodes
    )

    def measure(params: Any) -> dict[str, jax.Array]:
        return task.validate(network, params, keys, state.env_params)

    return jax.lax.map(measure, candidates(state.snapshots, state.online))


def run_agent(config: TrainConfig, state: Any) -> Any:
    """The run's agent: the final parameters, or with K > 0 the chosen candidate."""
    if not config.snapshots:
        return state.online
    best = chosen_candidate(state.validation, state.hparams)
    return jax.tree.map(lambda c: c[best], candidates(state.snapshots, state.online))
