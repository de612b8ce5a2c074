"""A results table's rows: an agent's runs pooled over seeds (:func:`study_row`), a single
policy (:func:`baseline_row`), the paper's Table III (:func:`paper_rows`) and a world's
frontier points (:func:`frontier_rows`); ``per_seed`` feeds the frontier margin (SPEC §9)."""

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from drqn_jax.evaluation import wilson_interval
from drqn_jax.experiments.frontier import t_interval, with_margin
from drqn_jax.experiments.machine import NOT_RECORDED
from drqn_jax.experiments.report import PAPER_EPISODES, PAPER_TABLE_III, PAPER_WORLD
from drqn_jax.learners.hyperparams import NOT_LEARNED, REWARD_ALONE, has_teacher, teachers_of


def _mean(runs: Sequence[Mapping[str, Any]], metric: str) -> float:
    values = [r[metric] for r in runs if r.get(metric) is not None]
    return float(np.mean(values)) if values else math.nan


def _std(runs: Sequence[Mapping[str, Any]], metric: str) -> float:
    values = [r[metric] for r in runs if r.get(metric) is not None]
    return float(np.std(values, ddof=1)) if len(values) > 1 else math.nan


def study_row(
    label: str,
    agent: str,
    runs: Sequence[Mapping[str, Any]],
    *,
    world: str,
    decision_steps: int | None = None,
) -> dict[str, Any]:
    """One table row from the JSON evaluations of an agent's runs (one per seed) in ``world``;
    a trained agent's ``decision_steps`` (ticks per decision) gives its ticks per seed.
    Collision-free interval: 95 % Student t across seeds, cut to [0, 1] (one run: Wilson);
    collisions per km pooled; ``per_seed``: seed, rate, speed for the frontier margin."""
    if not runs:
        raise ValueError(f"study_row {label!r}: no runs")
    rates = np.array([r["collision_free_rate"] for r in runs], np.float64)
    if len(runs) > 1:
        low, high = t_interval(rates)
        interval, interval_kind = (max(low, 0.0), min(high, 1.0)), "t over seeds"
    else:
        interval, interval_kind = tuple(runs[0]["collision_free_ci"]), "Wilson over episodes"
    episodes = [r["num_episodes"] for r in runs]
    collisions = sum(round(n * (1.0 - r)) for n, r in zip(episodes, rates, strict=True))
    km = sum(n * r["avg_distance_m"] for n, r in zip(episodes, runs, strict=True)) / 1000.0
    free = [round(n * r) for n, r in zip(episodes, rates, strict=True)]
    free_distance = [r.get("avg_distance_collision_free_m") for r in runs]
    pooled_free = [(k, d) for k, d in zip(free, free_distance, strict=True) if k and d is not None]
    trained = [r for r in runs if "env_steps" in r or "trained_on" in r]  # runs per device below
    row = {
        "label": label,
        "agent": agent,
        "world": world,
        "teacher": any(has_teacher(r.get("teacher")) for r in runs),
        "learned": teachers_of(runs),
        "seeds": len(runs),
        "episodes": int(episodes[0]),
        "diverged": sum(bool(r.get("diverged")) for r in runs),
        "collision_free_rate": float(rates.mean()),
        "collision_free_ci": (float(interval[0]), float(interval[1])),
        "interval": interval_kind,
        "avg_speed_kmh": _mean(runs, "avg_speed_kmh"),
        "avg_speed_kmh_std": _std(runs, "avg_speed_kmh"),
        "avg_speed_authors_kmh": _mean(runs, "avg_speed_authors_kmh"),
        "struck_while_stopped_rate": _mean(runs, "struck_while_stopped_rate"),
        "avg_distance_m": _mean(runs, "avg_distance_m"),
        "avg_distance_collision_free_m": (
            sum(k * d for k, d in pooled_free) / sum(k for k, _ in pooled_free)
            if pooled_free
            else math.nan
        ),
        "goal_rate": _mean(runs, "goal_rate"),
        "avg_return": _mean(runs, "avg_return"),
        "env_steps_per_seed": _mean(runs, "env_steps"),
        "devices": dict(Counter(r.get("trained_on", NOT_RECORDED) for r in trained)),
        "train_wall_s_per_seed": _mean(runs, "train_wall_s"),
        "train_wall_seeds": sum(r.get("train_wall_s") is not None for r in runs),
        "collisions_per_km": collisions / km if km > 0 else math.nan,
        "per_seed": [
            {
                "seed": r.get("values", {}).get("run.seed"),
                "collision_free_rate": r["collision_free_rate"],
                "avg_speed_kmh": r["avg_speed_kmh"],
            }
            for r in runs
        ],
    }
    if decision_steps is not None:
        row.update(
            decision_steps=decision_steps,
            ticks_per_seed=decision_steps * row["env_steps_per_seed"],
        )
    return row


def baseline_row(
    label: str, result: Mapping[str, Any], *, world: str, decision_steps: int | None = None
) -> dict[str, Any]:
    """A row of a single policy evaluated once (rule-based agent, one trained seed): Wilson."""
    return study_row(label, result["agent"], [result], world=world, decision_steps=decision_steps)


def _setting_text(params: Mapping[str, float]) -> str:
    names = {"v_max_kmh": "v_max", "v_cap_kmh": "cap", "corridor_margin": "margin"}
    units = {"v_max_kmh": " km/h", "v_cap_kmh": " km/h", "lookahead": " m", "horizon": " s"}
    return ", ".join(f"{names.get(k, k)} {v:g}{units.get(k, '')}" for k, v in params.items())


def frontier_rows(record: Mapping[str, Any], limit_kmh: float) -> list[dict[str, Any]]:
    """A ``world_frontier`` record as rows with ``params`` and margin: the rule-based points
    (margin 0) and the privileged planner's."""
    world = record["world"]
    kinds = [("rule_based", "rule-based frontier", "rule-based")]
    kinds += [("planner", "privileged planner (true state + simulator)", "planner")]
    rows = []
    for kind, label, agent in kinds:
        for point in record.get(kind, {}).get("points", []):
            result = {**point, "agent": agent, "teacher": NOT_LEARNED}
            row = baseline_row(f"{label}: {_setting_text(point['params'])}", result, world=world)
            rows.append({**with_margin(row, record, limit_kmh), "params": point["params"]})
    return rows


def paper_rows() -> list[dict[str, Any]]:
    """The paper's Table III as rows, with the Wilson interval its 10 episodes allow."""
    return [
        {
            "label": "paper (CARLA)",
            "agent": agent,
            "world": PAPER_WORLD,
            "teacher": False,
            "learned": NOT_LEARNED if agent == "rule-based" else REWARD_ALONE,
            "seeds": 1,
            "episodes": PAPER_EPISODES,
            "diverged": 0,
            "collision_free_rate": free / PAPER_EPISODES,
            "collision_free_ci": wilson_interval(free, PAPER_EPISODES),
            "interval": "Wilson over episodes",
            "avg_speed_kmh": speed,
            "avg_speed_kmh_std": math.nan,
            "avg_speed_authors_kmh": math.nan,
            "struck_while_stopped_rate": math.nan,
            "avg_distance_m": distance,
            "avg_distance_collision_free_m": math.nan,
            "goal_rate": math.nan,
            "collisions_per_km": math.nan,
        }
        for agent, free, speed, distance in PAPER_TABLE_III
    ]
