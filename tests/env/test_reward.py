"""The reward (drqn_jax/env/collision.py; SPEC §5), each term and the total by hand.

With the defaults (v_ref = 15 km/h, stopped below 0.1 m/s, TTC threshold 3 s):
r_v = 1 - (v_ref - v) / v_ref while 0.1 <= v <= v_ref, -1 below 0.1 m/s, -0.5
above v_ref; r_nc = TTC - 3 when TTC <= 3 s; r_c = -10; the total is the first
row that applies (collision, near collision, speed). The expected values are
written out here, not computed by the module's formulas; the env's step is
checked to report ``reward(collision, ttc, speed)`` of its own state.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.collision import reward, speed_reward, time_to_collision
from drqn_jax.env.params import KMH
from drqn_jax.env.state import STEER
from tests.scenes import FAR_X, LANE_Y, make_ego, make_peds, make_state

V_REF = 15.0 / 3.6  # m/s
INF = math.inf


@pytest.fixture(scope="module")
def ttc_fn(static):
    return jax.jit(time_to_collision, static_argnums=3)


@pytest.mark.parametrize(
    ("v", "want"),
    [
        (V_REF, 1.0),  # at the limit
        (0.5 * V_REF, 0.5),  # linear in v: 1 - (v_ref - v) / v_ref = v / v_ref
        (0.25 * V_REF, 0.25),
        (3.0, 0.72),  # 3 m/s of 4.1667
        (0.1, 0.024),  # at stopped_speed the ego counts as moving
        (0.099, -1.0),  # below it: stopped
        (0.0, -1.0),
        (V_REF + 0.01, -0.5),  # over the limit
        (50.0 * KMH, -0.5),
    ],
)
def test_speed_reward_by_hand(params, v, want):
    got = speed_reward(jnp.float32(v), params)
    assert got.dtype == jnp.float32 and got.shape == ()
    assert float(got) == pytest.approx(want, abs=1e-6)


def test_speed_reward_reads_its_parameters(params):
    p = params.replace(v_ref=10.0, stopped_speed=1.0, reward_stopped=-2.0, reward_overspeed=-0.25)
    v = jnp.array([5.0, 10.0, 0.99, 1.0, 10.5], jnp.float32)
    want = [0.5, 1.0, -2.0, 0.1, -0.25]
    np.testing.assert_allclose(np.asarray(speed_reward(v, p)), want, atol=1e-6)


@pytest.mark.parametrize(
    ("collided", "ttc", "v", "want"),
    [
        # collision: r_c, whatever the TTC and the speed
        (True, 0.0, V_REF, -10.0),
        (True, INF, 0.0, -10.0),
        (True, 2.0, 2.0 * V_REF, -10.0),
        # near collision (TTC <= 3 s): r_nc = TTC - 3, whatever the speed
        (False, 0.0, V_REF, -3.0),
        (False, 1.2, V_REF, -1.8),
        (False, 2.5, 2.0 * V_REF, -0.5),
        (False, 2.9, 0.05, -0.1),
        (False, 3.0, V_REF, 0.0),  # the threshold itself is a near collision
        # otherwise the speed reward
        (False, 3.1, V_REF, 1.0),
        (False, INF, 0.5 * V_REF, 0.5),
        (False, INF, 0.0, -1.0),
        (False, INF, 2.0 * V_REF, -0.5),
    ],
)
def test_reward_takes_the_first_row_that_applies(params, collided, ttc, v, want):
    got = reward(jnp.asarray(collided), jnp.float32(ttc), jnp.float32(v), params)
    assert got.dtype == jnp.float32 and got.shape == ()
    assert float(got) == pytest.approx(want, abs=1e-6)


def test_reward_reads_its_parameters(params):
    p = params.replace(reward_collision=-5.0, ttc_threshold=2.0)
    assert float(reward(jnp.asarray(True), jnp.float32(INF), jnp.float32(0.0), p)) == -5.0
    assert float(reward(jnp.asarray(False), jnp.float32(1.5), jnp.float32(V_REF), p)) == -0.5
    # 2.5 s is no longer a near collision: the speed reward
    assert float(reward(jnp.asarray(False), jnp.float32(2.5), jnp.float32(V_REF), p)) == 1.0


@pytest.mark.parametrize(
    ("weight", "ttc", "want"), [(0.1, 0.0, -0.3), (0.1, 1.2, -0.18), (0.0, 1.2, 0.0)]
)
def test_reward_near_collision_weight_scales_r_nc_only(params, weight, ttc, want):
    """r_nc = w (TTC - 3); r_c and r_v do not read w."""
    p = params.replace(reward_near_collision_weight=weight)
    assert float(reward(jnp.asarray(False), jnp.float32(ttc), jnp.float32(V_REF), p)) == (
        pytest.approx(want, abs=1e-6)
    )
    assert float(reward(jnp.asarray(True), jnp.float32(ttc), jnp.float32(V_REF), p)) == -10.0
    assert float(reward(jnp.asarray(False), jnp.float32(INF), jnp.float32(V_REF), p)) == 1.0


def test_near_collision_weight_one_is_ttc_minus_3_bit_for_bit(params):
    ttc = jnp.linspace(0.0, 3.0, 31, dtype=jnp.float32)
    one = params.replace(reward_near_collision_weight=1.0)
    got = reward(jnp.asarray(False), ttc, jnp.float32(V_REF), one)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(ttc - jnp.float32(3.0)))


def test_reward_batched_and_bounded(params):
    """Elementwise over a batch (vmap ≡ broadcasting), and in [-10, 1] with the defaults."""
    v = jnp.append(jnp.linspace(0.0, 20.0, 201, dtype=jnp.float32), jnp.float32(V_REF))
    ttc = jnp.array([0.0, 0.7, 1.5, 3.0, 3.1, INF], jnp.float32)
    collided = jnp.array([False, True])
    grid = jnp.meshgrid(collided, ttc, v, indexing="ij")
    broadcast = reward(*grid, params)
    mapped = jax.vmap(lambda c, t, s: reward(c, t, s, params))(*(g.ravel() for g in grid))
    np.testing.assert_array_equal(np.asarray(mapped).reshape(broadcast.shape), broadcast)
    assert float(broadcast.min()) == -10.0 and float(broadcast.max()) == 1.0
    assert np.all(np.asarray(broadcast[1]) == -10.0)


def test_step_reports_the_speed_reward_when_nobody_is_near(env, params, static):
    """The env's total on a step with no pedestrian near (TTC inf): r_v of the speed after
    the step, written out by hand."""
    s = 20.0
    for v in (0.0, 2.0, V_REF, 6.0):
        state = make_state(make_ego(params, static, s=s, v=v), make_peds(static, [], park_x=FAR_X))
        _, r, _, _, info = jax.jit(env.advance)(state, jnp.int32(STEER), params)
        speed = float(info["speed"])
        assert math.isinf(float(info["ttc"])) and not bool(info["collision"])
        want = -1.0 if speed < 0.1 else -0.5 if speed > V_REF else speed / V_REF
        assert float(r) == pytest.approx(want, abs=1e-6), (v, speed)


def test_step_reports_ttc_and_near_collision_reward(env, params, static, ttc_fn):
    """The env's total on a step with a pedestrian 1.8 s ahead: r_nc of the TTC it reports,
    which is time_to_collision of the stepped state."""
    s, v = 20.0, 4.0
    state = make_state(make_ego(params, static, s=s, v=v), make_peds(static, [(s + 10.0, LANE_Y)]))
    stepped, r, terminated, _, info = jax.jit(env.advance)(state, jnp.int32(STEER), params)
    ttc = float(info["ttc"])
    assert ttc == float(ttc_fn(stepped.ego, stepped.pedestrians, params, static))
    # After one step the gap is 7.45 - (about 0.4) m at about 4 m/s: 1.8 s.
    assert ttc == pytest.approx(1.8, abs=1e-6)
    assert float(r) == pytest.approx(ttc - params.ttc_threshold, abs=1e-6)
    assert not bool(terminated) and not bool(info["collision"])
