"""The yardstick (SPEC §9): the rule-based family's frontier, the planner's ceiling, margins.
An agent is judged against the best collision-free rate the rule-based agent (paper §V-E) reaches
*at the agent's own average speed*: the upper concave hull of the family's Pareto points over
:data:`RULE_BASED_SETTINGS`, swept as one program (``lax.map`` over settings of a ``vmap`` over
episodes). Also Student-t intervals and interquartile means across seeds (Agarwal et al. 2021)."""

import itertools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.agents.base import Agent
from drqn_jax.agents.planner import PlannerParams, planner_agent
from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_agent
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.evaluation import EpisodeMetrics, episode_keys, rollouts, summarize_outcomes
from drqn_jax.programs import jit_in_store

# two-sided 95 % Student-t quantiles for 1..30 degrees of freedom, then the normal's
T_975 = (
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228,
    2.201, 2.179, 2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086,
    2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042, 1.960,
)  # fmt: skip


def t_interval(values: np.ndarray) -> tuple[float, float]:
    """95 % Student-t interval of the mean of ``values`` (n,); nan with fewer than 2."""
    x = np.asarray(values, np.float64)
    n = len(x)
    if n < 2:
        return (math.nan, math.nan)
    half = T_975[min(n - 1, len(T_975)) - 1] * x.std(ddof=1) / math.sqrt(n)
    return (float(x.mean() - half), float(x.mean() + half))


def interquartile_mean(values: np.ndarray) -> float:
    """Mean of the middle 50 % of ``values`` (n,), fractional ends weighted."""
    x = np.sort(np.asarray(values, np.float64))
    n = len(x)
    lo, hi = 0.25 * n, 0.75 * n
    weights = np.clip(np.minimum(np.arange(1, n + 1), hi) - np.maximum(np.arange(n), lo), 0, 1)
    return float(np.sum(weights * x) / np.sum(weights))


#: The wide grid (3000 settings) behind :data:`RULE_BASED_SETTINGS` (``frontier --wide``).
WIDE_GRID: dict[str, tuple[float, ...]] = {
    "v_max_kmh": (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0),
    "lookahead": (3.5, 7.0, 14.0, 20.0, 25.0),
    "horizon": (0.0, 1.0, 2.0, 4.0, 5.0),
    "corridor_margin": (0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5),
}

#: The privileged planner's speed caps (km/h): its frontier, the ceiling.
PLANNER_CAPS_KMH: tuple[float, ...] = (3.0, 5.0, 7.0, 10.0, 15.0)


def grid_settings(grid: Mapping[str, Sequence[float]]) -> list[dict[str, float]]:
    """Every combination of ``grid``'s axes, in order (the last axis fastest)."""
    names = list(grid)
    return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*grid.values())]


#: The default rule-based settings ``(v_max km/h, lookahead m, horizon s, corridor_margin m)``:
#: the :data:`WIDE_GRID` Pareto set, thinned to 30 by ``benchmarks/frontier_settings.py``
#: keeping every envelope vertex (docs/results.md, "The yardstick").
_SETTINGS = (
    (1.0, 3.5, 0.0, 0.0),
    (12.0, 25.0, 5.0, 1.5),
    (14.0, 14.0, 1.0, 1.5),
    (15.0, 25.0, 5.0, 1.0),
    (13.0, 25.0, 2.0, 1.0),
    (14.0, 25.0, 1.0, 1.0),
    (13.0, 20.0, 1.0, 1.0),
    (15.0, 14.0, 4.0, 1.0),
    (11.0, 3.5, 5.0, 1.0),
    (15.0, 25.0, 4.0, 0.75),
    (15.0, 20.0, 5.0, 0.75),
    (15.0, 14.0, 5.0, 0.75),
    (15.0, 14.0, 2.0, 0.75),
    (15.0, 3.5, 2.0, 0.75),
    (15.0, 3.5, 1.0, 0.75),
    (15.0, 20.0, 0.0, 2.0),
    (15.0, 25.0, 0.0, 1.5),
    (15.0, 20.0, 0.0, 1.5),
    (15.0, 7.0, 5.0, 0.5),
    (15.0, 3.5, 0.0, 2.5),
    (15.0, 7.0, 4.0, 0.5),
    (15.0, 25.0, 0.0, 1.0),
    (15.0, 7.0, 0.0, 1.0),
    (15.0, 7.0, 0.0, 0.5),
    (15.0, 3.5, 0.0, 0.75),
    (15.0, 3.5, 0.0, 0.5),
    (15.0, 7.0, 1.0, 0.25),
    (15.0, 7.0, 0.0, 0.25),
    (15.0, 7.0, 2.0, 0.0),
    (15.0, 3.5, 0.0, 0.0),
)
RULE_BASED_SETTINGS: tuple[dict[str, float], ...] = tuple(
    dict(zip(WIDE_GRID, s, strict=True)) for s in _SETTINGS
)


@jit_in_store("make_agent", "env")
def sweep_family(
    make_agent: Callable[[Any], Agent],
    settings: Any,
    keys: jax.Array,
    env: UrbanPedestrians,
    params: EnvParams,
) -> EpisodeMetrics:
    """EpisodeMetrics (S, N) of every setting (leaves (S,)) on the (N,) episode ``keys``, as
    :func:`~drqn_jax.evaluation.evaluate` measures them except TTC and return (NaN; near-collision
    steps 0), which XLA then drops, halving the cost."""

    def one(setting: Any) -> EpisodeMetrics:
        # the rollout inline, not run_episodes' jitted call: XLA drops the unused TTC
        # only within one computation
        agent = make_agent(setting)
        m = rollouts(agent, keys, env, params)
        return m.replace(  # the reward's near-collision term reads the TTC too
            min_ttc=jnp.full_like(m.min_ttc, jnp.nan),
            near_collision_steps=jnp.zeros_like(m.near_collision_steps),
            episode_return=jnp.full_like(m.episode_return, jnp.nan),
        )

    return jax.lax.map(one, settings)


def pareto_points(points: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The Pareto-efficient points (collision-free rate vs average speed), by speed."""
    kept: list[Mapping[str, Any]] = []
    best_rate = -math.inf
    # by speed, fastest first, the safer first at equal speed: a point is efficient
    # when it is safer than every faster (or equally fast, safer) point before it
    order = sorted(points, key=lambda p: (-p["avg_speed_kmh"], -p["collision_free_rate"]))
    for p in order:
        if p["collision_free_rate"] > best_rate:
            kept.append(p)
            best_rate = p["collision_free_rate"]
    return kept[::-1]


def frontier_vertices(points: Sequence[Mapping[str, Any]]) -> list[tuple[float, float]]:
    """The vertices ``(speed km/h, rate)`` of the upper concave hull of the Pareto points; linear
    between vertices, as mixing two settings per episode reaches the whole segment."""
    xy = sorted({(p["avg_speed_kmh"], p["collision_free_rate"]) for p in pareto_points(points)})
    hull: list[tuple[float, float]] = []
    for x, y in xy:  # Andrew's monotone chain, the upper part
        while len(hull) >= 2:
            (x1, y1), (x2, y2) = hull[-2], hull[-1]
            if (x2 - x1) * (y - y1) - (y2 - y1) * (x - x1) < 0.0:
                break  # the last vertex lies above the chord: it stays
            hull.pop()
        hull.append((x, y))
    return hull


def frontier_rate(vertices: Sequence[Sequence[float]], speed_kmh: float | np.ndarray) -> Any:
    """The frontier's collision-free rate at ``speed_kmh`` (SPEC §9): linear between the
    vertices, clamped to the end vertices' rates beyond them."""
    v = np.asarray(vertices, np.float64).reshape(-1, 2)
    if v.shape[0] == 0:
        raise ValueError("frontier_rate: the frontier has no points")
    return np.interp(speed_kmh, v[:, 0], v[:, 1])


def above_speed_limit(speeds_kmh: Sequence[float], limit_kmh: float) -> bool:
    """Whether any average speed exceeds the limit (float32 rounding aside; SPEC §9)."""
    return max(speeds_kmh) > limit_kmh * (1 + 1e-6)


def seed_margins(
    runs: Sequence[Mapping[str, Any]], vertices: Sequence[Sequence[float]]
) -> np.ndarray:
    """(n,): each run's collision-free rate minus the frontier at the run's own speed."""
    rates = np.array([r["collision_free_rate"] for r in runs], np.float64)
    speeds = np.array([r["avg_speed_kmh"] for r in runs], np.float64)
    return rates - frontier_rate(vertices, speeds)


def frontier_margin(
    row: Mapping[str, Any], vertices: Sequence[Sequence[float]], limit_kmh: float
) -> tuple[float, tuple[float, float]] | None:
    """``(margin, (low, high))``: a row's collision-free rate minus the frontier at its own speed,
    95 % interval (SPEC §9); None if any seed exceeds ``limit_kmh``. Several seeds (``per_seed``):
    mean of per-seed margins, Student t; one policy: its Wilson interval minus the frontier."""
    seeds = row.get("per_seed") or []
    speeds = [s["avg_speed_kmh"] for s in seeds] if len(seeds) > 1 else [row["avg_speed_kmh"]]
    if above_speed_limit(speeds, limit_kmh):
        return None
    if len(seeds) > 1:
        margins = seed_margins(seeds, vertices)
        return float(margins.mean()), t_interval(margins)
    at = float(frontier_rate(vertices, row["avg_speed_kmh"]))
    low, high = row["collision_free_ci"]
    return float(row["collision_free_rate"] - at), (float(low - at), float(high - at))


def _sweep_points(
    make_agent: Callable[[Any], Agent],
    each: Sequence[Any],
    settings: Sequence[Mapping[str, float]],
    key: jax.Array,
    num_episodes: int,
    env: UrbanPedestrians,
    params: EnvParams,
) -> tuple[list[dict[str, Any]], float]:
    """One point per setting (``each``: its agent's params) on episodes ``fold_in(key, i)``,
    i < N: ``summarize_outcomes`` of its episodes and its ``params``; and the wall time."""
    start = time.perf_counter()
    keys = episode_keys(key, num_episodes)
    batched = jax.tree.map(lambda *xs: jnp.stack(xs), *each)
    metrics = sweep_family(make_agent, batched, keys, env, params)
    host = jax.tree.map(np.asarray, metrics)
    points = [
        {"params": dict(s), **summarize_outcomes(jax.tree.map(lambda x, i=i: x[i], host))}
        for i, s in enumerate(settings)
    ]
    return points, time.perf_counter() - start


def with_margin(
    row: Mapping[str, Any], record: Mapping[str, Any], limit_kmh: float
) -> dict[str, Any]:
    """``row`` with ``frontier_margin``/``_ci`` against ``record``'s rule-based frontier
    (None, ``above_speed_limit`` True, for a row faster than ``limit_kmh``)."""
    vertices = frontier_vertices(record["rule_based"]["points"])
    found = frontier_margin(row, vertices, limit_kmh)
    if found is None:
        none = {"frontier_margin": None, "frontier_margin_ci": None}
        return {**row, **none, "above_speed_limit": True}
    margin, interval = found
    return {**row, "frontier_margin": margin, "frontier_margin_ci": interval}


#: Uniform ranges (low, high, unit) of :func:`random_settings`, off :data:`WIDE_GRID`'s points.
REVIEWER_RANGES = {
    "lookahead": (2.0, 25.0, "m"),
    "horizon": (0.0, 5.0, "s"),
    "corridor_margin": (0.0, 2.5, "m"),
    "speed_band_kmh": (0.25, 2.0, "km/h"),
}


def random_settings(n: int, seed: int, limit_kmh: float) -> list[dict[str, float]]:
    """``n`` rule-based settings drawn uniformly from :data:`REVIEWER_RANGES`, rounded to 0.01."""
    rng = np.random.default_rng(seed)
    ranges = {"v_max_kmh": (1.0, limit_kmh, "km/h"), **REVIEWER_RANGES}
    return [
        {name: round(float(rng.uniform(low, high)), 2) for name, (low, high, _) in ranges.items()}
        for _ in range(n)
    ]


def reviewer_check(
    points: Sequence[Mapping[str, Any]], vertices: Sequence[Sequence[float]], seed: int
) -> str:
    """A sentence: how many random ``points`` beat the frontier, the nearest's distance,
    and how many have a Wilson interval wholly above it."""
    at = frontier_rate(vertices, np.array([p["avg_speed_kmh"] for p in points]))
    excess = np.array([p["collision_free_rate"] for p in points]) - at
    lows = np.array([p["collision_free_ci"][0] for p in points]) - at
    ranges = ", ".join(
        f"{name.removesuffix('_kmh').replace('_', ' ')} {low:g}–{high:g} {unit}"
        for name, (low, high, unit) in REVIEWER_RANGES.items()
    )
    best = round(100 * float(excess.max()), 1)
    side = "on it" if best == 0 else f"{abs(best):.1f} points {'above' if best > 0 else 'below'} it"
    return (
        f"{len(points)} random rule-based settings (v_max 1 km/h to the limit, {ranges}; "
        f"seed {seed}) on the same episodes: {int((excess > 0).sum())} lie above the frontier "
        f"at their own speed (the highest {side}), {int((lows > 0).sum())} with a Wilson "
        "interval wholly above it"
    )


def world_frontier(
    env: UrbanPedestrians,
    params: EnvParams,
    key: jax.Array,
    num_episodes: int,
    *,
    world: str,
    seed: int,
    planner: PlannerParams | None = None,
    settings: Sequence[Mapping[str, float]] | None = None,
    caps_kmh: Sequence[float] = PLANNER_CAPS_KMH,
    keep_all: bool = False,
) -> dict[str, Any]:
    """A world's frontiers on episodes ``fold_in(key, i)``, i < N, as JSON-ready ``{"world",
    "episodes", "seed", "speed_limit_kmh", "rule_based", ["planner"]}`` (``keep_all`` adds
    ``"swept_points"``); settings above ``params.v_ref`` raise ValueError."""
    limit_kmh = float(params.v_ref) / KMH
    chosen = list(RULE_BASED_SETTINGS if settings is None else settings)
    speeds = [s["v_max_kmh"] for s in chosen] + list(caps_kmh if planner is not None else ())
    too_fast = [v for v in speeds if v > limit_kmh * (1 + 1e-6)]
    if too_fast:
        raise ValueError(f"speed {too_fast[0]} km/h: above the speed limit {limit_kmh:g} km/h")
    sweep = (key, num_episodes, env, params)
    each = [
        RuleBasedParams(
            v_max=s["v_max_kmh"] * KMH,
            speed_band=s.get("speed_band_kmh", 1.0) * KMH,  # ±1 km/h unless set
            lookahead=s["lookahead"],
            horizon=s["horizon"],
            corridor_margin=s["corridor_margin"],
        )
        for s in chosen
    ]
    points, wall = _sweep_points(rule_based_agent, each, chosen, *sweep)
    rule = {"points": pareto_points(points), "swept": len(points), "wall_time_s": wall}
    if keep_all:
        rule["swept_points"] = points
    record = {"world": world, "episodes": num_episodes, "seed": seed}
    record |= {"speed_limit_kmh": limit_kmh, "rule_based": rule}
    if planner is not None:
        caps = [{"v_cap_kmh": float(c), "horizon_steps": planner.horizon_steps} for c in caps_kmh]
        each = [planner.replace(v_cap=jnp.float32(c * KMH)) for c in caps_kmh]
        found, wall = _sweep_points(planner_agent, each, caps, *sweep)
        record["planner"] = {"points": found, "wall_time_s": wall}
    return record
