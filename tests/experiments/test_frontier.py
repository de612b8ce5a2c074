"""The yardstick (drqn_jax/experiments/frontier.py; SPEC §9): Pareto points, the frontier, margins,
and the family sweep against a plain evaluation of the same setting."""

from __future__ import annotations

import json
import math

import jax
import numpy as np
import pytest

from drqn_jax import cli
from drqn_jax.agents import RuleBasedParams, rule_based_agent
from drqn_jax.env.params import KMH
from drqn_jax.evaluation import evaluate, wilson_interval
from drqn_jax.experiments.frontier import (
    PLANNER_CAPS_KMH,
    RULE_BASED_SETTINGS,
    frontier_margin,
    frontier_rate,
    frontier_vertices,
    grid_settings,
    pareto_points,
    random_settings,
    reviewer_check,
    t_interval,
    with_margin,
    world_frontier,
)
from drqn_jax.experiments.report import load_results


def _point(speed: float, rate: float) -> dict:
    return {"avg_speed_kmh": speed, "collision_free_rate": rate}


#: A hand-made family: (0, 1.0) the standing car, then a concave frontier with two
#: dominated points and one under the chord of its neighbours.
FAMILY = [
    _point(0.0, 1.0),
    _point(2.0, 0.9),
    _point(3.0, 0.5),  # dominated by (4, .7)
    _point(4.0, 0.7),
    _point(6.0, 0.44),  # Pareto-efficient, but under the chord from (4, .7) to (8, .2)
    _point(8.0, 0.2),
    _point(8.0, 0.1),  # as fast as (8, .2), less safe
]

#: km/h: the hand-made world's speed limit, past the family's fastest point.
LIMIT = 15.0


def test_pareto_points_drop_the_dominated_ones():
    kept = [(p["avg_speed_kmh"], p["collision_free_rate"]) for p in pareto_points(FAMILY)]
    assert kept == [(0.0, 1.0), (2.0, 0.9), (4.0, 0.7), (6.0, 0.44), (8.0, 0.2)]


def test_the_frontier_is_the_upper_concave_hull_of_the_pareto_points():
    v = frontier_vertices(FAMILY)
    assert v == [(0.0, 1.0), (2.0, 0.9), (4.0, 0.7), (8.0, 0.2)]
    # a point added can raise the frontier, never lower it
    assert frontier_vertices([*FAMILY, _point(1.0, 0.9)]) == v
    assert frontier_vertices([*FAMILY, _point(6.0, 0.48)]) == [*v[:3], (6.0, 0.48), v[3]]


def test_frontier_rate_is_linear_between_vertices_and_flat_beyond():
    v = frontier_vertices(FAMILY)
    assert frontier_rate(v, 1.0) == pytest.approx(0.95)
    assert frontier_rate(v, 3.0) == pytest.approx(0.8)  # above the dominated (3, .5)
    assert frontier_rate(v, 6.0) == pytest.approx(0.45)  # on the chord, above (6, .44)
    assert frontier_rate(v, 7.0) == pytest.approx(0.325)
    assert frontier_rate(v, 8.0) == pytest.approx(0.2)
    assert frontier_rate(v, 12.0) == pytest.approx(0.2)  # the fastest point's rate beyond
    np.testing.assert_allclose(frontier_rate(v, np.array([0.0, 5.0])), [1.0, 0.575])
    with pytest.raises(ValueError, match="no points"):
        frontier_rate([], 1.0)


def test_margin_of_single_policies_on_above_and_below_the_frontier():
    """A single policy: its rate minus the frontier at its speed, and its Wilson
    interval shifted by the same amount."""
    v = frontier_vertices(FAMILY)
    for free, speed, sign in [(450, 6.0, 0), (600, 6.0, 1), (200, 6.0, -1)]:
        ci = wilson_interval(free, 1000)
        row = {"avg_speed_kmh": speed, "collision_free_rate": free / 1000, "collision_free_ci": ci}
        margin, (low, high) = frontier_margin(row, v, LIMIT)
        assert margin == pytest.approx(free / 1000 - 0.45)
        assert (low, high) == pytest.approx((ci[0] - 0.45, ci[1] - 0.45))
        above, below = low > 0.0, high < 0.0
        assert (above, below) == (sign > 0, sign < 0)


def test_margin_of_a_trained_config_is_over_seeds_each_at_its_own_speed():
    v = frontier_vertices(FAMILY)
    seeds = [
        {"collision_free_rate": 0.97, "avg_speed_kmh": 1.0},  # frontier 0.95: +0.02
        {"collision_free_rate": 0.95, "avg_speed_kmh": 2.0},  # 0.9: +0.05
        {"collision_free_rate": 0.7, "avg_speed_kmh": 3.0},  # 0.8: -0.1
    ]
    row = {
        "per_seed": seeds,
        "avg_speed_kmh": 2.0,  # the mean speed: not what the margin reads
        "collision_free_rate": float(np.mean([s["collision_free_rate"] for s in seeds])),
        "collision_free_ci": (0.0, 1.0),
    }
    margin, interval = frontier_margin(row, v, LIMIT)
    diffs = np.array([0.02, 0.05, -0.1])
    assert margin == pytest.approx(diffs.mean())
    assert interval == pytest.approx(t_interval(diffs))


def test_no_margin_above_the_speed_limit():
    """The family keeps the limit, so the frontier has no point past it: a policy (or
    any one seed of a trained config) faster than the limit has no margin, however
    safe; at the limit it has one (the fastest point's rate, SPEC §9)."""
    v = frontier_vertices(FAMILY)
    one = {"avg_speed_kmh": 15.5, "collision_free_rate": 0.9, "collision_free_ci": (0.88, 0.92)}
    assert frontier_margin(one, v, LIMIT) is None
    at_limit = frontier_margin({**one, "avg_speed_kmh": LIMIT}, v, LIMIT)
    assert at_limit[0] == pytest.approx(0.9 - 0.2)
    seeds = [{"collision_free_rate": 0.9, "avg_speed_kmh": s} for s in (6.0, 16.0)]
    assert frontier_margin({**one, "avg_speed_kmh": 11.0, "per_seed": seeds}, v, LIMIT) is None
    record = {"rule_based": {"points": FAMILY}}
    row = with_margin(one, record, LIMIT)
    assert row["above_speed_limit"] and row["frontier_margin"] is None
    assert row["frontier_margin_ci"] is None
    assert "above_speed_limit" not in with_margin({**one, "avg_speed_kmh": 6.0}, record, LIMIT)


def test_the_reviewer_check_counts_settings_above_the_frontier():
    v = frontier_vertices(FAMILY)  # 45 % at 6 km/h
    tried = [
        {**_point(6.0, 0.50), "collision_free_ci": (0.47, 0.53)},  # above, interval too
        {**_point(6.0, 0.46), "collision_free_ci": (0.43, 0.49)},  # above, interval not
        {**_point(6.0, 0.30), "collision_free_ci": (0.27, 0.33)},  # below
    ]
    line = reviewer_check(tried, v, seed=7)
    assert line.startswith("3 random rule-based settings (v_max 1 km/h to the limit")
    assert "horizon 0–5 s, corridor margin 0–2.5 m, speed band 0.25–2 km/h; seed 7) on " in line
    assert line.endswith(
        "same episodes: 2 lie above the frontier at their own speed (the highest 5.0 points "
        "above it), 1 with a Wilson interval wholly above it"
    )
    assert "(the highest 15.0 points below it), 0 with" in reviewer_check(tried[2:], v, seed=7)
    standing = [{**_point(0.0, 1.0), "collision_free_ci": (0.99, 1.0)}]  # the frontier's start
    assert "0 lie above the frontier at their own speed (the highest on it)" in reviewer_check(
        standing, v, seed=7
    )
    drawn = random_settings(50, seed=7, limit_kmh=15.0)
    assert drawn == random_settings(50, seed=7, limit_kmh=15.0)
    assert all(1.0 <= d["v_max_kmh"] <= 15.0 and 0.0 <= d["horizon"] <= 5.0 for d in drawn)
    assert all(0.25 <= d["speed_band_kmh"] <= 2.0 for d in drawn)


def test_grid_settings_is_the_product_of_the_axes():
    settings = grid_settings({"a": (1.0, 2.0), "b": (3.0,), "c": (4.0, 5.0)})
    assert len(settings) == 4
    assert settings[1] == {"a": 1.0, "b": 3.0, "c": 5.0}


@pytest.fixture(scope="module")
def small_sweep(env, params):
    grid = {
        "v_max_kmh": (1.0, 6.0, 15.0),
        "lookahead": (7.0,),
        "horizon": (0.0, 2.0),
        "corridor_margin": (0.5,),
    }
    found = world_frontier(
        env,
        params,
        jax.random.key(3),
        6,
        world="w",
        seed=3,
        settings=grid_settings(grid),
        keep_all=True,
    )
    return found["rule_based"]["swept_points"]


def test_sweep_points_equal_evaluations_of_the_same_settings(env, params, small_sweep):
    """What a reviewer would do: evaluate one setting of the sweep on its own on the
    same episodes; every outcome metric is the same number."""
    assert len(small_sweep) == 6
    point = small_sweep[3]  # v_max 6 km/h, horizon 2 s
    assert point["params"] == {
        "v_max_kmh": 6.0,
        "lookahead": 7.0,
        "horizon": 2.0,
        "corridor_margin": 0.5,
    }
    rb = RuleBasedParams(v_max=6.0 * KMH, lookahead=7.0, horizon=2.0, corridor_margin=0.5)
    alone = evaluate(rule_based_agent(rb), jax.random.key(3), 6, env, params)
    for name, value in point.items():
        if name not in ("params", "avg_return"):  # the sweep measures no reward
            assert alone[name] == value or (math.isnan(value) and math.isnan(alone[name])), name
    assert math.isnan(point["avg_return"])


def test_the_standing_setting_anchors_the_frontier(small_sweep):
    standing = small_sweep[0]  # v_max = 1 km/h: the band never lets it accelerate
    assert standing["avg_speed_kmh"] == 0.0
    assert standing["collision_free_rate"] == 1.0
    assert frontier_vertices(small_sweep)[0] == (0.0, 1.0)


def test_the_frontier_command_stores_both_frontiers(tmp_path, capsys):
    """``drqn-jax frontier``: the rule-based Pareto points and the planner's caps as rows
    of a results section (each with its parameters, interval and speed), the swept
    points in OUT/frontier.json, and the wall time of each sweep."""
    out, results = tmp_path / "f", tmp_path / "results.json"
    # smoke's world on 2 episodes: the programs test_study's studies compile
    argv = ["frontier", "--config", "smoke", "--episodes", "2", "--out", str(out), "--quiet"]
    assert cli.main([*argv, "--results", str(results), "--no-png", "--check", "3"]) == 0
    printed = capsys.readouterr().out
    assert "rule_based" in printed and "planner" in printed and "s in all" in printed
    record = load_results(results)
    rows = [r for r in record["rows"] if r["section"] == "frontier"]
    planner = [r for r in rows if r["agent"] == "planner"]
    rule = [r for r in rows if r["agent"] == "rule-based" and r["world"] != "CARLA (paper)"]
    assert [r["params"]["v_cap_kmh"] for r in planner] == list(PLANNER_CAPS_KMH)
    assert all(
        r["label"].startswith("privileged planner (true state + simulator)") for r in planner
    )
    # every Pareto point is on or under the envelope; its vertices are on it
    assert rule and all(r["frontier_margin"] <= 1e-12 for r in rule)
    assert any(r["frontier_margin"] == 0.0 for r in rule)
    assert all(
        set(r["params"]) == {"v_max_kmh", "lookahead", "horizon", "corridor_margin"} for r in rule
    )
    about = record["sections"]["frontier"]
    assert about["rule_based_wall_time_s"] > 0 and about["planner_wall_time_s"] > 0
    (check,) = about["comparisons"]  # the reviewer's random settings against the frontier
    assert check.startswith("3 random rule-based settings") and "lie above the frontier" in check
    (stored,) = about["frontiers"].values()
    assert "swept_points" not in stored["rule_based"]  # every point: OUT/frontier.json only
    swept = json.loads((out / "frontier.json").read_text())["rule_based"]
    assert len(swept["swept_points"]) == swept["swept"] == len(RULE_BASED_SETTINGS)
    assert {r["collision_free_rate"] for r in rule} <= {
        p["collision_free_rate"] for p in swept["swept_points"]
    }


def test_the_frontier_command_refuses_a_cap_above_the_limit(tmp_path, capsys):
    argv = ["frontier", "--episodes", "2", "--caps", "5,20", "--out", str(tmp_path), "--no-png"]
    assert cli.main(argv) == 2
    assert "20.0 km/h: above the speed limit 15 km/h" in capsys.readouterr().err


def test_evaluate_the_planner(capsys):
    """``--agent planner``: every SPEC §8 metric, labelled as not learned."""
    assert cli.main(["evaluate", "--agent", "planner", "--episodes", "2", "--json", "-"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["agent"] == "planner" and payload["teacher"] == "– (not learned)"
    assert payload["collision_free_rate"] == 1.0
