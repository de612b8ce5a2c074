"""The sentences under a results table (SPEC §9): a row against the rule-based frontier,
the paper's claim, paired comparisons over seeds, and Table III at scale's goal."""

from __future__ import annotations

import numpy as np

from drqn_jax.config import load_config
from drqn_jax.experiments.baselines import frontier_key
from drqn_jax.experiments.frontier import with_margin
from drqn_jax.experiments.report import study_table
from drqn_jax.experiments.verdicts import (
    Paired,
    claim_verdict,
    compare_paired,
    frontier_comparison,
    goal_verdict,
    paired_margin,
    study_comparisons,
)
from tests.helpers import HAND_FRONTIER, judged_row

#: A hand-made planner's ceiling: 100 % standing, 95 % at 15 km/h.
CEILING = [(0.0, 1.0), (15.0, 0.95)]


def _seeds(rates, speed):
    """Runs of seeds 0, 1, … with ``rates`` collision-free at ``speed`` km/h each."""
    return [
        {"values": {"run.seed": k}, "collision_free_rate": r, "avg_speed_kmh": speed}
        for k, r in enumerate(rates)
    ]


def _compare(name, runs, other, others, vertices, limit_kmh):
    """:func:`compare_paired` of ``runs`` against ``others`` (seed by seed)."""
    paired = paired_margin((name, other), runs, others, vertices, limit_kmh)
    return compare_paired((name, other), paired, limit_kmh)


def _trained(name, agent, rates, speed, teacher=False):
    """A trained arm's row over its seeds, with its margin to ``HAND_FRONTIER``."""
    row = {
        "label": f"drqn_jax: {name}",
        "agent": agent,
        "teacher": teacher,
        "avg_speed_kmh": speed,
        "collision_free_rate": float(np.mean(rates)),
        "per_seed": _seeds(rates, speed),
    }
    return with_margin(row, HAND_FRONTIER, 15.0)


def test_the_verdict_follows_the_margin_and_the_speed():
    """Supported only above the frontier at its own speed *and* at least as fast as
    the paper's DRQN (6.09 km/h); above it but slower is not shown; below is reversed."""
    above = claim_verdict(judged_row(0.8, 8.0))  # the frontier at 8 km/h: 25 %
    assert "is supported:" in above and "+55.0 (+52.0 to +58.0) points at 8.00 km/h" in above
    slow = claim_verdict(judged_row(0.99, 1.0))  # the frontier: 95 %
    assert "not shown:" in slow and "slower than the paper's DRQN (6.09 km/h)" in slow
    overlap = claim_verdict(judged_row(0.51, 6.0))
    assert "not shown:" in overlap and "not distinguishable" in overlap
    assert "reversed:" in claim_verdict(judged_row(0.2, 6.5))
    assert "below the rule-based frontier at its own speed" in frontier_comparison(
        judged_row(0.2, 6.5)
    )


def test_a_row_above_the_speed_limit_has_no_margin_and_no_verdict_of_safety():
    """A DRQN faster than the limit: "–" with the reason in the table, and the claim
    not shown whatever its collision-free rate (SPEC §9)."""
    fast = judged_row(0.99, 30.0)
    assert fast["frontier_margin"] is None and fast["above_speed_limit"]
    assert "| 99.0 (96.0–102.0) | – (above the speed limit) |" in study_table([fast])
    verdict = claim_verdict(fast)
    assert "not shown: the DRQN drives faster than the speed limit" in verdict
    assert "faster than the speed limit" in frontier_comparison(fast)


def test_paired_comparison_is_of_margins_over_the_seeds_both_arms_trained():
    """Seed i against seed i, each seed's margin at its own speed: a slower arm gets no
    credit for being slower."""
    flat = [(0.0, 0.5), (10.0, 0.5)]  # a frontier of 50 % at every speed

    a = _seeds([0.9, 0.8, 0.85, 0.5], 5.0)
    b = _seeds([0.5, 0.45, 0.5], 5.0)  # seed 3 untrained: left out of the pairs
    line = _compare("drqn", a, "dqn", b, flat, 15.0)
    assert line.startswith(
        "drqn − dqn, margin to the rule-based frontier, paired over 3 seeds: +36.7 points"
    )
    assert line.endswith("drqn above")
    close = _seeds([0.5, 0.6, 0.4], 5.0)
    near = _compare("drqn", close, "dqn", _seeds([0.55, 0.5, 0.42], 5.0), flat, 15.0)
    assert near.endswith("drqn not distinguishable")
    assert _compare("drqn", a[:1], "dqn", b, flat, 15.0) is None
    # on a falling frontier (100 % standing, 0 % at 10 km/h) the same rates at a lower
    # speed are a smaller margin: 0.9 - 0.9 at 1 km/h against 0.5 - 0.5 at 5 km/h
    falling = [(0.0, 1.0), (10.0, 0.0)]
    slow = _seeds([0.9, 0.9], 1.0)
    assert "+0.0 points" in _compare("a", slow, "b", _seeds([0.5, 0.5], 5.0), falling, 15.0)
    # a seed past the limit has no margin, so the pair has none either (SPEC §9)
    fast = _seeds([0.9, 0.9, 0.9], 16.0)
    assert _compare("drqn", fast, "dqn", b, flat, 15.0).endswith(
        "none, drqn drives faster than the 15 km/h limit in some seed (SPEC §9)"
    )


def test_the_goal_is_met_only_where_every_part_of_it_is():
    """At 7 km/h (≥ 6.09), above the frontier (37.5 % there), 92 % against the
    planner's 97.7 % at that speed (the whole interval within 10 points) and above the
    twin: met. Each part that fails says so, and the goal is not met."""
    twin = {"pqn-dqn": Paired(3, 0.3, (0.2, 0.4))}
    met = goal_verdict(_trained("pqn", "pqn", [0.91, 0.92, 0.93], 7.0), CEILING, 15.0, twin)
    assert "is met by drqn_jax: pqn: 7.00 km/h, at or above 6.09;" in met
    assert "-5.7 points (-8.2 to -3.2): within 10 points; above pqn-dqn (+30.0 points" in met
    spread = _trained("pqn", "pqn", [0.8, 0.92, 0.99], 7.0)  # its interval reaches -10
    assert "is not met" in goal_verdict(spread, CEILING, 15.0, twin)
    assert "not within 10 points" in goal_verdict(spread, CEILING, 15.0, twin)
    slow = goal_verdict(_trained("pqn", "pqn", [0.94, 0.96, 0.98], 1.0), CEILING, 15.0, twin)
    assert "is not met" in slow and "1.00 km/h, not at or above 6.09" in slow
    assert "not above 0" in slow  # 96 % at 1 km/h, the frontier 95 %: overlaps
    others = {
        "pqn-dqn": Paired(3, 0.05, (-0.02, 0.12)),
        "pqn-stack": None,
        "fast": Paired(3, too_fast="fast"),
    }
    lines = goal_verdict(_trained("pqn", "pqn", [0.91, 0.92, 0.93], 7.0), CEILING, 15.0, others)
    assert "is not met" in lines and "not above pqn-dqn (+5.0 points (-2.0 to +12.0))" in lines
    assert "fewer than 2 seeds in common with pqn-stack" in lines
    assert "not above fast (fast faster than the speed limit)" in lines


def test_a_study_judges_the_claim_and_the_goal_on_a_teacher_free_recurrent_q_network():
    """The first arm, a teacher-free recurrent PQN: the claim, then the goal against its
    memoryless twins (the feed-forward PQNs, not PPO), then each row against the
    frontier and the first arm against each other arm. A teacher-guided first arm
    gets neither verdict; without the planner's ceiling there is no goal."""
    names = ["pqn", "pqn-dqn", "pqn-stack", "ppo"]
    configs = {n: load_config(n) for n in names}
    speeds = {"pqn": 7.0, "pqn-dqn": 7.0, "pqn-stack": 6.5, "ppo": 8.0}
    rates = {"pqn": [0.91, 0.92, 0.93], "pqn-dqn": [0.4, 0.5, 0.45]}
    rates |= {"pqn-stack": [0.5, 0.45, 0.4], "ppo": [0.3, 0.2, 0.25]}
    agents = {"pqn": "pqn", "pqn-dqn": "pqn-ff", "pqn-stack": "pqn-ff", "ppo": "ppo"}
    trained = [(_trained(n, agents[n], rates[n], speeds[n]), c) for n, c in configs.items()]
    runs = {n: _seeds(rates[n], speeds[n]) for n in names}
    planner = {"points": [{"avg_speed_kmh": v, "collision_free_rate": r} for v, r in CEILING]}
    frontiers = {frontier_key(configs["pqn"]): {**HAND_FRONTIER, "planner": planner}}
    lines = study_comparisons(trained, names, runs, frontiers)
    assert lines[0].startswith("The paper's claim (a DRQN safer") and "is supported" in lines[0]
    assert (
        lines[1].startswith("Table III at scale's goal") and "is met by drqn_jax: pqn" in lines[1]
    )
    assert "above pqn-dqn" in lines[1] and "above pqn-stack" in lines[1] and "ppo" not in lines[1]
    assert lines[2].startswith("drqn_jax: pqn (pqn) at 7.00 km/h: above the rule-based frontier")
    assert [line.split(",")[0] for line in lines[-3:]] == [f"pqn − {n}" for n in names[1:]]
    assert len(lines) == 2 + 4 + 3
    guided = [(_trained("pqn", "pqn", rates["pqn"], 7.0, teacher=True), configs["pqn"])]
    assert not any(
        "claim" in s or "goal" in s
        for s in study_comparisons(guided + trained[1:], names, runs, frontiers)
    )
    bare = {frontier_key(configs["pqn"]): HAND_FRONTIER}
    assert not any("goal" in line for line in study_comparisons(trained, names, runs, bare))
