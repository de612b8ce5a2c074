"""The sentences under a results table (SPEC §9): each row against the rule-based frontier at its
own speed, the paper's claim, arms paired seed by seed, and Table III at scale's goal. "Above" means
the 95 % interval lies above; every number comes from the rows."""

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

from drqn_jax.config import Config
from drqn_jax.experiments.baselines import frontier_key
from drqn_jax.experiments.frontier import (
    above_speed_limit,
    frontier_margin,
    frontier_vertices,
    seed_margins,
    t_interval,
)
from drqn_jax.experiments.report import (
    CLAIM,
    GOAL,
    PAPER_DRQN_SPEED_KMH,
    margin_cell,
    points_interval,
)

#: The agents that are recurrent Q-networks (a DRQN in the paper's sense).
RECURRENT_Q_NETWORKS = ("drqn", "pqn")
#: Goal: points the DRQN's collision-free rate may lie under the planner's ceiling.
GOAL_CEILING_POINTS = 10.0


def _side(low: float, high: float) -> str:
    return "above" if low > 0.0 else "below" if high < 0.0 else "not distinguishable from"


def frontier_comparison(row: Mapping[str, Any]) -> str:
    """A row against the rule-based frontier at its own speed, as a sentence."""
    speed = f"{row['label']} ({row['agent']}) at {row['avg_speed_kmh']:.2f} km/h"
    if row.get("above_speed_limit"):
        return (
            f"{speed}: faster than the speed limit (in some seed), where the rule-based "
            "frontier has no point: no margin (SPEC §9)"
        )
    side = _side(*row["frontier_margin_ci"])
    margin = margin_cell(row)
    return f"{speed}: {side} the rule-based frontier at its own speed (margin {margin} points)"


def claim_verdict(drqn: Mapping[str, Any]) -> str:
    """One line on the paper's claim (Table III) from the DRQN's row (SPEC §9): supported only
    if its frontier margin lies above 0 *and* it drives at least ``PAPER_DRQN_SPEED_KMH``."""
    speed = drqn["avg_speed_kmh"]
    low, high = drqn["frontier_margin_ci"] or (math.nan, math.nan)  # none above the limit
    where = f"the DRQN is {_side(low, high)} the rule-based frontier at its own speed"
    if drqn.get("above_speed_limit"):
        verdict = (
            "not shown: the DRQN drives faster than the speed limit, where the rule-based "
            "family, which keeps the limit, has no point to compare it with"
        )
    elif low > 0.0 and speed >= PAPER_DRQN_SPEED_KMH:
        verdict = f"supported: {where}, at least as fast as the paper's DRQN"
    elif low > 0.0:
        verdict = (
            f"not shown: {where}, but slower than the paper's DRQN ({PAPER_DRQN_SPEED_KMH} km/h)"
        )
    else:
        verdict = f"{'reversed' if high < 0.0 else 'not shown'}: {where}"
    return (
        f"{CLAIM} (a DRQN safer than the rule-based agent, at the paper's DRQN's "
        f"{PAPER_DRQN_SPEED_KMH} km/h or faster) is {verdict} (margin {margin_cell(drqn)} "
        f"points at {speed:.2f} km/h)."
    )


@dataclasses.dataclass(frozen=True)
class Paired:
    """Two arms' frontier margins paired over ``seeds``: mean ``difference`` (first minus
    second), its 95 % t ``interval``; ``too_fast``: the arm above the speed limit, if any."""

    seeds: int
    difference: float = math.nan
    interval: tuple[float, float] = (math.nan, math.nan)
    too_fast: str | None = None


def paired_margin(
    names: tuple[str, str],
    runs: Sequence[Mapping[str, Any]],
    others: Sequence[Mapping[str, Any]],
    vertices: Sequence[Sequence[float]],
    limit_kmh: float,
) -> Paired | None:
    """``runs``' frontier margins (SPEC §9) against ``others``', seed i against seed i; None
    with fewer than 2 common seeds."""
    mine, theirs = ({r["values"].get("run.seed"): r for r in rs} for rs in (runs, others))
    common = sorted(set(mine) & set(theirs))
    if len(common) < 2:
        return None
    for label, own in zip(names, (mine, theirs), strict=True):
        if above_speed_limit([own[k]["avg_speed_kmh"] for k in common], limit_kmh):
            return Paired(len(common), too_fast=label)
    mine_margins, their_margins = (
        seed_margins([own[k] for k in common], vertices) for own in (mine, theirs)
    )
    diff = mine_margins - their_margins
    return Paired(len(common), float(diff.mean()), t_interval(diff))


def compare_paired(names: tuple[str, str], paired: Paired | None, limit_kmh: float) -> str | None:
    """A :func:`paired_margin` of ``names`` as a sentence (points, 95 % interval); None
    without one."""
    if paired is None:
        return None
    name, other = names
    if paired.too_fast is not None:
        return (
            f"{name} − {other}, margin to the rule-based frontier: none, {paired.too_fast} "
            f"drives faster than the {limit_kmh:g} km/h limit in some seed (SPEC §9)"
        )
    side = _side(*paired.interval).removesuffix(" from")
    return (
        f"{name} − {other}, margin to the rule-based frontier, paired over {paired.seeds} "
        f"seeds: {100 * paired.difference:+.1f} points {points_interval(*paired.interval)}: "
        f"{name} {side}"
    )


def goal_verdict(
    drqn: Mapping[str, Any],
    ceiling: Sequence[Sequence[float]],
    limit_kmh: float,
    twins: Mapping[str, Paired | None],
) -> str:
    """Table III at scale's goal on the DRQN's row, met only if every part is: speed at least
    the paper's DRQN's, frontier margin above 0, within :data:`GOAL_CEILING_POINTS` of the
    planner's ``ceiling``, and above each memoryless twin (``twins``: paired margins)."""
    speed = drqn["avg_speed_kmh"]
    fast = speed >= PAPER_DRQN_SPEED_KMH
    interval = drqn.get("frontier_margin_ci")
    above = interval is not None and interval[0] > 0.0
    parts = [
        (fast, f"{speed:.2f} km/h, {'not ' * (not fast)}at or above {PAPER_DRQN_SPEED_KMH}"),
        (above, f"margin {margin_cell(drqn)} points: {'not ' * (not above)}above 0"),
    ]
    gap = frontier_margin(drqn, ceiling, limit_kmh)
    if gap is None:
        parts.append((False, "faster than the speed limit, where the planner has no point"))
    else:
        mean, (low, high) = gap
        near = low >= -GOAL_CEILING_POINTS / 100
        text = (
            f"collision-free rate minus the planner's ceiling at its own speed "
            f"{100 * mean:+.1f} points {points_interval(low, high)}: "
            f"{'within' if near else 'not within'} {GOAL_CEILING_POINTS:g} points"
        )
        parts.append((near, text))
    for name, paired in twins.items():
        if paired is None:
            parts.append((False, f"fewer than 2 seeds in common with {name}"))
        elif paired.too_fast is not None:
            too_fast = f"{paired.too_fast} faster than the speed limit"
            parts.append((False, f"not above {name} ({too_fast})"))
        else:
            ahead = paired.interval[0] > 0.0
            points = f"{100 * paired.difference:+.1f} points {points_interval(*paired.interval)}"
            parts.append((ahead, f"{'not ' * (not ahead)}above {name} ({points})"))
    met = all(ok for ok, _ in parts)
    return (
        f"{GOAL} (at {PAPER_DRQN_SPEED_KMH} km/h or faster, a margin "
        f"above 0, within {GOAL_CEILING_POINTS:g} points of the planner's ceiling at its "
        f"own speed, above each memoryless twin paired over seeds) is "
        f"{'met' if met else 'not met'} by {drqn['label']}: "
        + "; ".join(text for _, text in parts)
        + "."
    )


def study_comparisons(
    trained: Sequence[tuple[dict[str, Any], Config]],
    names: Sequence[str],
    runs: Mapping[str, Sequence[Mapping[str, Any]]],
    frontiers: Mapping[str, Mapping[str, Any]],
) -> list[str]:
    """The sentences under a study's table: claim and goal verdicts (first arm a teacher-free
    DRQN), each trained row against its frontier, the first arm paired with the others."""
    comparisons = [frontier_comparison(row) for row, _ in trained]
    if not names:
        return comparisons
    headline, config = trained[0]
    first, key, limit = names[0], frontier_key(config), config.speed_limit_kmh()
    vertices = frontier_vertices(frontiers[key]["rule_based"]["points"])
    arms = {row["label"].removeprefix("drqn_jax: "): c for row, c in trained}
    rivals = [name for name in names[1:] if frontier_key(arms[name]) == key]
    paired = {n: paired_margin((first, n), runs[first], runs[n], vertices, limit) for n in rivals}
    if headline["agent"] in RECURRENT_Q_NETWORKS and not headline["teacher"]:
        verdicts = [claim_verdict(headline)]
        learner = config.train_config().algorithm
        memoryless = [n for n in rivals if arms[n].train_config().network.kind != "drqn"]
        twins = {n: paired[n] for n in memoryless if arms[n].train_config().algorithm == learner}
        if twins and "planner" in frontiers[key]:
            ceiling = frontier_vertices(frontiers[key]["planner"]["points"])
            verdicts.append(goal_verdict(headline, ceiling, limit, twins))
        comparisons = verdicts + comparisons
    sentences = [compare_paired((first, n), paired[n], limit) for n in rivals]
    return comparisons + [s for s in sentences if s is not None]
