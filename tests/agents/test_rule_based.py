"""The rule-based agent (drqn_jax/agents/rule_based.py; SPEC §6) in hand-built scenes.

It stops short of a standing pedestrian (closed loop, ``tests/scenes.py``), its
labels of the replay's records are its actions, and its anticipation horizon
brakes for exactly the pedestrians that walk into the corridor in time.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_action, rule_based_labels
from drqn_jax.env.grid import GridInputs
from drqn_jax.env.params import KMH
from drqn_jax.env.state import BRAKE
from tests import scenes
from tests.scenes import LANE_Y, SCAN_STEPS, first_index, make_ego, make_peds, make_state


@pytest.fixture(scope="module")
def run_scene(env):
    return functools.partial(scenes.run_scene, env)


@pytest.mark.parametrize("v0_kmh", [0.0, 15.0])
def test_rule_based_stops_before_standing_pedestrian(env, params, static, run_scene, v0_kmh):
    s0 = float(params.ego_start_s)
    ped_x = s0 + 30.0
    state = make_state(
        make_ego(params, static, s=s0, v=v0_kmh * KMH), make_peds(static, [(ped_x, LANE_Y)])
    )
    final, out = run_scene(state, params, rule=True)

    assert not np.any(out["collision"])
    assert not np.any(out["terminated"])
    assert float(final.ego.v) == 0.0
    assert np.all(out["v"][-50:] == 0.0), "the ego does not stay stopped"
    gap = ped_x - params.ped_radius - (float(final.ego.s) + 0.5 * params.ego_length)
    rb = RuleBasedParams()
    assert 0.0 < gap <= rb.lookahead
    # It drove at the speed limit before braking (within the ±1 km/h band).
    assert np.max(out["v"]) >= (15.0 - 1.0) * KMH
    assert np.max(out["v"]) <= (15.0 + 1.5) * KMH
    # First brake only once the pedestrian is within the look-ahead of the bumper.
    first_brake = first_index(out["action"] == BRAKE)
    s_before = out["s"][first_brake - 1] if first_brake > 0 else s0
    assert ped_x - (s_before + 0.5 * params.ego_length) <= rb.lookahead
    assert np.all(out["action"][first_brake:] == BRAKE)
    # The standing pedestrian stayed where it was (never replaced, never moved).
    np.testing.assert_array_equal(
        out["ped_position"][:, 0], np.broadcast_to(np.float32([ped_x, LANE_Y]), (SCAN_STEPS, 2))
    )


def test_rule_based_labels_of_records_are_its_actions(params, static):
    """``rule_based_labels`` on the replay's records (``GridInputs``) gives the
    action ``rule_based_action`` takes in the true state, for any leading shape:
    braking for a pedestrian in the corridor within the look-ahead, not for one
    beyond it or on the sidewalk, and tracking the speed limit otherwise."""
    rb = RuleBasedParams()
    s = 40.0
    front = s + 0.5 * params.ego_length
    scenes = [
        (0.0, [(front + 3.0, LANE_Y)]),  # in the corridor: brake
        (4.0, [(front + rb.lookahead + 2.0, LANE_Y)]),  # beyond the look-ahead
        (4.2, [(front + 3.0, -5.0)]),  # on the sidewalk
        (3.0, [(front + 6.0, LANE_Y + 0.5)]),  # in the corridor, off-centre: brake
        (4.9, []),  # nobody: slow down from above the limit
        (2.0, []),  # nobody: accelerate
    ]
    states = [
        make_state(make_ego(params, static, s=s, v=v), make_peds(static, peds))
        for v, peds in scenes
    ]
    batch = jax.tree.map(lambda *x: jnp.stack(x).reshape((2, 3, *x[0].shape)), *states)
    expected = [int(rule_based_action(st, params, rb, static)) for st in states]
    assert expected[0] == expected[3] == BRAKE and BRAKE not in expected[1:3] + expected[4:]
    records = GridInputs.of(batch.ego, batch.pedestrians)
    labels = rule_based_labels(records, params, rb, static)
    assert labels.shape == (2, 3)
    np.testing.assert_array_equal(np.asarray(labels).ravel(), expected)


def test_rule_based_horizon_anticipates_pedestrians_walking_into_the_corridor(params, static):
    """``horizon`` = h > 0: also brake for a pedestrian that, walking on, enters the
    corridor within h seconds, within the look-ahead of the bumper, before the bumper
    (moving on at the ego's speed) has passed it; h = 0 is the paper's rule."""
    s, v = 40.0, 4.0
    front = s + 0.5 * params.ego_length
    kerb = LANE_Y - 2.0  # 0.3 m outside the corridor (half width 0.9 + 0.3 + 0.5)
    scenes = {  # pedestrian (x, y), velocity, ego speed -> brakes with h = 0.1, 0.5, 1
        "steps in, enters in 0.2 s": ((front + 3.0, kerb), (0.0, 1.5), v, (0, 1, 1)),
        "steps in slowly, enters in 0.75 s": ((front + 3.0, kerb), (0.0, 0.4), v, (0, 0, 1)),
        "walks away": ((front + 3.0, kerb), (0.0, -1.5), v, (0, 0, 0)),
        "walks along the kerb": ((front + 3.0, kerb), (1.5, 0.0), v, (0, 0, 0)),
        "the bumper passes first": ((front + 0.2, kerb), (0.0, 1.5), v, (0, 0, 0)),
        "... unless the ego stands": ((front + 0.2, kerb), (0.0, 1.5), 0.0, (0, 1, 1)),
        "beyond the look-ahead": ((front + 8.0, kerb), (0.0, 1.5), v, (0, 0, 0)),
        "into the look-ahead in 0.4 s": ((front + 7.4, LANE_Y), (-1.0, 0.0), v, (0, 1, 1)),
        "standing beyond it": ((front + 7.5, LANE_Y), (0.0, 0.0), v, (0, 0, 0)),
    }
    action = jax.jit(rule_based_action, static_argnums=3)
    labels = jax.jit(rule_based_labels, static_argnums=3)
    for name, (position, velocity, speed, brakes) in scenes.items():
        state = make_state(
            make_ego(params, static, s=s, v=speed),
            make_peds(static, [position], velocities=[velocity]),
        )
        records = GridInputs.of(state.ego, state.pedestrians)  # what the replay holds
        for horizon, want in zip((0.0, 0.1, 0.5, 1.0), (0, *brakes), strict=True):
            rb = RuleBasedParams(horizon=horizon)
            got = int(action(state, params, rb, static))
            assert (got == BRAKE) == bool(want), (name, horizon)
            assert int(labels(records, params, rb, static)) == got
