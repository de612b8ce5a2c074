"""The privileged planner (drqn_jax/agents/planner.py; SPEC §9) in hand-built scenes.

It is the ceiling of the results tables, so it must not collide where braking at
once avoids the pedestrian, including where the rule-based agent of the paper does
collide; it waits for a pedestrian crossing its lane and drives on after; and it
never drives faster than its cap.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from drqn_jax.agents import planner_agent, rule_based_agent
from drqn_jax.agents.planner import PlannerParams, planner_action
from drqn_jax.env.params import KMH
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, STEER
from tests.scenes import LANE_Y, make_ego, make_peds, make_state, run_agent_scene

#: On the road at the lane's outer edge: inside the authors' collision zone (the whole
#: lane), outside the rule-based agent's corridor (half width 0.9 + 0.3 + 0.5 m).
EDGE_Y = -3.48


def test_planner_stops_for_a_pedestrian_the_rule_based_agent_drives_into(env, params, static):
    s0 = float(params.ego_start_s)
    ped_x = s0 + 30.0
    state = make_state(
        make_ego(params, static, s=s0, v=15.0 * KMH), make_peds(static, [(ped_x, EDGE_Y)])
    )
    _, rule = run_agent_scene(env, state, params, rule_based_agent())
    assert rule["collision"].any(), "the scene must be one the paper's rule misses"

    final, out = run_agent_scene(env, state, params, planner_agent())
    assert not out["collision"].any()
    assert float(final.ego.v) == 0.0
    # it stopped short of the authors' zone reaching the pedestrian (3.5 m ahead of
    # the centre), and not far back: it drove until braking was needed
    gap = ped_x - float(final.ego.s)
    assert params.authors_zone_front < gap < params.authors_zone_front + 10.0
    assert out["v"].max() >= 14.0 * KMH


def test_planner_waits_for_a_crossing_pedestrian_then_drives_on(env, params, static):
    s0 = float(params.ego_start_s)
    ped_x = s0 + 20.0
    peds = make_peds(
        static, [(ped_x, -5.0)], targets=[(ped_x, 8.0)], speeds=[1.0], velocities=[(0.0, 1.0)]
    )
    final, out = run_agent_scene(
        env, make_state(make_ego(params, static, s=s0), peds), params, planner_agent()
    )
    assert not out["collision"].any()
    assert (out["v"] == 0.0)[20:].any(), "it never waited"
    assert float(final.ego.s) > ped_x + 5.0, "it did not drive on once the lane was clear"


@pytest.mark.parametrize(("v_kmh", "want"), [(5.0, ACCELERATE), (10.0, STEER), (12.0, SLOW_DOWN)])
def test_planner_tracks_its_cap_on_an_empty_road(params, static, env, v_kmh, want):
    state = make_state(make_ego(params, static, s=20.0, v=v_kmh * KMH), make_peds(static, []))
    act = jax.jit(planner_action, static_argnums=0)
    assert int(act(env, state, params, PlannerParams(v_cap=10.0 * KMH))) == want


def test_planner_brakes_when_no_candidate_is_safe(params, static, env):
    """A pedestrian standing in the lane just ahead of a fast car: every candidate
    collides, so it brakes."""
    s = 20.0
    state = make_state(
        make_ego(params, static, s=s, v=15.0 * KMH), make_peds(static, [(s + 4.0, LANE_Y)])
    )
    act = jax.jit(planner_action, static_argnums=0)
    assert int(act(env, state, params, PlannerParams())) == BRAKE


def test_planner_params_are_validated():
    with pytest.raises(ValueError, match=r"PlannerParams\.horizon_steps"):
        PlannerParams(horizon_steps=0)
    with pytest.raises(ValueError, match=r"PlannerParams\.v_cap"):
        PlannerParams(v_cap=0.0)
    assert isinstance(PlannerParams(horizon_steps=10).horizon_steps, int)
    assert np.isclose(float(PlannerParams().v_cap), 15.0 * KMH)
