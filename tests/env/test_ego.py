"""The ego vehicle (drqn_jax/env/ego.py): setpoint, PID, plant (SPEC §2).

Closed-loop checks run one jitted ``lax.scan`` of ``ego_step`` over a fixed
number of steps (one compile for the whole module, plus its vmapped twin);
unit checks of the PID and the plant compare against the formulas of SPEC §2
written out by hand.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.ego import (
    desired_speed,
    ego_step,
    initial_ego,
    pid_step,
    plant_step,
    throttle_brake,
)
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, STEER, EgoState

ROLLOUT_STEPS = 100  # one fixed length: a single compile serves every closed-loop test
V_15 = 15.0 * KMH


def _rollout(ego: EgoState, actions: jax.Array, params: EnvParams):
    """Apply ``actions`` (T,) in turn; return the final ego and per-step (v, s, accel)."""

    def body(e, a):
        e = ego_step(e, a, params)
        return e, (e.v, e.s, e.accel)

    return jax.lax.scan(body, ego, actions)


@pytest.fixture(scope="module")
def params(env_params):
    return env_params[1]


@pytest.fixture(scope="module")
def static(env_params):
    return env_params[0].static


@pytest.fixture(scope="module")
def rollout():
    return jax.jit(_rollout)


@pytest.fixture(scope="module")
def batched_rollout():
    return jax.jit(jax.vmap(_rollout, in_axes=(0, 0, None)))


def _constant(action: int) -> jax.Array:
    return jnp.full((ROLLOUT_STEPS,), action, jnp.int32)


def _moving_ego(params, static, v: float) -> EgoState:
    """The ego at speed ``v`` with no acceleration and an empty PID history."""
    ego = initial_ego(params, static)
    return ego.replace(v=jnp.float32(v), v_setpoint=jnp.float32(v))


def _first_index(mask: np.ndarray) -> int:
    """Index of the first True (the test fails if there is none)."""
    hits = np.flatnonzero(mask)
    assert hits.size > 0, "condition never reached"
    return int(hits[0])


# --- 1. accelerate from rest -----------------------------------------------


def test_initial_ego_matches_spec(params, static):
    ego = initial_ego(params, static)
    assert float(ego.s) == pytest.approx(5.0)
    assert float(ego.v) == 0.0
    assert float(ego.accel) == 0.0
    assert float(ego.v_setpoint) == 0.0
    assert ego.pid_errors.shape == (static.pid_window,)
    assert int(ego.pid_count) == 0


def test_accelerate_from_rest_reaches_speed_limit_in_plant_time(params, static, rollout):
    ego = initial_ego(params, static)
    _, (v, s, accel) = rollout(ego, _constant(ACCELERATE), params)
    v = np.asarray(v)
    dt = params.dt
    a_max = params.throttle_max * params.accel_throttle  # 3.0 m/s^2, no resistance
    a_sat = a_max - params.rolling_resistance  # 2.9 m/s^2 saturated while moving
    step = _first_index(v >= np.float32(V_15))
    t_reach = (step + 1) * dt  # v[k] is the speed after k + 1 steps

    upper = V_15 / a_sat + params.accel_lag + 2 * dt  # ~1.94 s
    lower = V_15 / a_max  # ~1.39 s: even without any lag it takes this long
    assert t_reach <= upper + 1e-6, (t_reach, upper)
    assert t_reach >= lower - 1e-6, (t_reach, lower)
    # The speed rises monotonically and the lagged acceleration never exceeds
    # the saturated command.
    assert np.all(np.diff(v[: step + 1]) > 0)
    assert np.all(np.asarray(accel)[: step + 1] <= a_max + 1e-5)
    # Position integrates the speed: s_k = s_{k-1} + v_k dt.
    s = np.asarray(s)
    np.testing.assert_allclose(np.diff(s), v[1:] * dt, rtol=1e-5, atol=1e-6)
    assert s[0] == pytest.approx(params.ego_start_s + v[0] * dt, abs=1e-6)


def test_first_accelerate_step_values(params, static):
    """One step from rest: u = Kp*1 km/h = 1 -> throttle 0.75 -> a_cmd 3.0 (not moving)."""
    ego = ego_step(initial_ego(params, static), jnp.int32(ACCELERATE), params)
    a_cmd = params.throttle_max * params.accel_throttle  # rolling resistance only while moving
    a1 = a_cmd * params.dt / params.accel_lag
    assert float(ego.accel) == pytest.approx(a1, rel=1e-6)
    assert float(ego.v) == pytest.approx(a1 * params.dt, rel=1e-6)
    assert float(ego.s) == pytest.approx(params.ego_start_s + a1 * params.dt**2, rel=1e-6)
    assert float(ego.v_setpoint) == pytest.approx(KMH, rel=1e-6)
    assert int(ego.pid_count) == 1
    assert float(ego.pid_errors[-1]) == pytest.approx(1.0, rel=1e-5)  # km/h


# --- 2. emergency braking ----------------------------------------------------


@pytest.mark.parametrize("v0_kmh", [15.0, 30.0, 50.0])
def test_emergency_brake_stops_within_analytic_distance(params, static, rollout, v0_kmh):
    v0 = v0_kmh * KMH
    ego = _moving_ego(params, static, v0)
    _, (v, s, _) = rollout(ego, _constant(BRAKE), params)
    v, s = np.asarray(v), np.asarray(s)

    stop = _first_index(v == 0.0)
    assert np.all(v >= 0.0)
    assert np.all(v[stop:] == 0.0), "the ego starts rolling again under brake"
    assert np.all(np.diff(v[: stop + 1]) < 0), "speed must drop at every step until stopped"
    assert np.all(s[stop:] == s[stop]), "position changes after the stop"

    distance = s[stop] - params.ego_start_s
    a_brk = params.accel_brake
    upper = v0**2 / (2 * a_brk) + v0 * params.accel_lag + v0 * params.dt
    lower = v0**2 / (2 * (a_brk + params.rolling_resistance))  # no lag at all
    assert distance <= upper, (distance, upper)
    assert distance >= lower, (distance, lower)
    # Stopping time is bounded the same way.
    t_stop = (stop + 1) * params.dt
    assert t_stop <= v0 / a_brk + params.accel_lag + 2 * params.dt
    assert t_stop >= v0 / (a_brk + params.rolling_resistance)


def test_brake_after_accelerating_stops_and_stays_stopped(params, static, rollout):
    """Reach 15 km/h by accelerating, then brake: speed hits exactly 0 and stays there."""
    ego = initial_ego(params, static)
    _, (v_acc, _, _) = rollout(ego, _constant(ACCELERATE), params)
    n_acc = _first_index(np.asarray(v_acc) >= np.float32(V_15)) + 1
    actions = jnp.where(jnp.arange(ROLLOUT_STEPS) < n_acc, ACCELERATE, BRAKE).astype(jnp.int32)
    final, (v, s, _) = rollout(ego, actions, params)
    v, s = np.asarray(v), np.asarray(s)
    v_start = v[n_acc - 1]
    assert v_start >= np.float32(V_15)
    stop = _first_index(v == 0.0)
    assert np.all(v >= 0.0)
    assert np.all(v[stop:] == 0.0)
    assert float(final.v) == 0.0
    assert float(final.accel) >= 0.0  # a car at rest carries no braking force
    # The accelerating car still has a positive lagged acceleration when the
    # brake starts: allow one more lag-time of travel at the starting speed.
    distance = s[stop] - s[n_acc - 1]
    upper = v_start**2 / (2 * params.accel_brake) + v_start * (2 * params.accel_lag + params.dt)
    assert 0.0 < distance <= upper
    # Braking leaves the setpoint at 0 and the PID history untouched.
    assert float(final.v_setpoint) == 0.0
    assert int(final.pid_count) == min(n_acc, static.pid_window)


# --- 3. slow_down is gentle --------------------------------------------------


@pytest.mark.parametrize("from_accelerating", [False, True])
def test_slow_down_decelerates_gently(params, static, rollout, from_accelerating):
    if from_accelerating:
        ego = initial_ego(params, static)
        _, (v_acc, _, _) = rollout(ego, _constant(ACCELERATE), params)
        n_acc = _first_index(np.asarray(v_acc) >= np.float32(V_15)) + 1
    else:
        ego = _moving_ego(params, static, V_15)
        n_acc = 0
    actions = jnp.where(jnp.arange(ROLLOUT_STEPS) < n_acc, ACCELERATE, SLOW_DOWN)
    _, (v, _, _) = rollout(ego, actions.astype(jnp.int32), params)
    v = np.concatenate([[np.float32(ego.v)], np.asarray(v)])[n_acc:]  # from the first slow_down
    v0 = v[0]
    assert v0 >= np.float32(V_15) - 1e-6
    decel = -np.diff(v) / params.dt
    assert np.max(decel) <= 3.0, np.max(decel)
    # The PID's brake is capped at brake_max: the deceleration never exceeds
    # brake_max*A_brk + c_roll (2.5 m/s^2), whatever the error history.
    assert np.max(decel) <= params.brake_max * params.accel_brake + params.rolling_resistance + 1e-4
    # It does slow down: within 1 s the speed has dropped by at least 1 m/s,
    # and it is non-increasing once the lag has flushed any leftover throttle.
    assert v[10] <= v0 - 1.0, (v0, v[10])
    assert np.all(np.diff(v[5:]) <= 0.0)
    assert np.all(v >= 0.0)
    assert v[-1] == 0.0  # slow_down all the way ends at rest


# --- 4. speed bounds over random action sequences ----------------------------


def test_speed_stays_in_bounds_under_random_actions(params, static, batched_rollout):
    batch = 8
    keys = jax.random.split(jax.random.key(1234), batch)
    # Half the sequences favour accelerate heavily so the 50 km/h cap is hit;
    # the other half are uniform over the four actions.
    probs = jnp.where(
        (jnp.arange(batch) % 2 == 0)[:, None],
        jnp.array([0.85, 0.05, 0.05, 0.05]),
        jnp.array([0.25, 0.25, 0.25, 0.25]),
    )
    actions = jax.vmap(
        lambda k, p: jax.random.choice(k, 4, (ROLLOUT_STEPS,), p=p).astype(jnp.int32)
    )(keys, probs)
    ego0 = jax.tree.map(
        lambda x: jnp.broadcast_to(x, (batch, *x.shape)), initial_ego(params, static)
    )
    _, (v, s, _) = batched_rollout(ego0, actions, params)
    v, s = np.asarray(v), np.asarray(s)
    v_max = np.float32(params.max_vehicle_speed)
    assert np.all(v >= 0.0)
    assert np.all(v <= v_max)
    assert np.all(np.diff(s, axis=1) >= 0.0), "the ego never moves backwards"
    # The accelerate-heavy sequences actually reach the cap (so the clip is exercised).
    assert np.max(v[0::2]) == pytest.approx(v_max, rel=1e-6)
    # Starting at the cap, always accelerate stays exactly at the cap.
    at_cap = _moving_ego(params, static, params.max_vehicle_speed)
    ego1 = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), at_cap)
    _, (v1, _, _) = batched_rollout(ego1, jnp.zeros_like(actions), params)
    assert np.all(np.asarray(v1) <= v_max)
    assert np.asarray(v1)[:, -1] == pytest.approx(v_max, rel=1e-6)


# --- 5. PID, pedals, setpoints, plant: formulas of SPEC §2 --------------------


def _ego(static, *, v=0.0, v_setpoint=0.0, accel=0.0, errors=None, count=0, s=5.0):
    k = static.pid_window
    errs = np.zeros(k, np.float32) if errors is None else np.asarray(errors, np.float32)
    return EgoState(
        s=jnp.float32(s),
        v=jnp.float32(v),
        accel=jnp.float32(accel),
        v_setpoint=jnp.float32(v_setpoint),
        pid_errors=jnp.asarray(errs),
        pid_count=jnp.int32(count),
    )


@pytest.mark.parametrize(
    ("mode", "base"),
    [("measured", 3.0), ("setpoint", 2.0)],
)
def test_desired_speed_per_action(static, mode, base):
    params = EnvParams(setpoint_mode=mode)
    ego = _ego(static, v=3.0, v_setpoint=2.0)
    expected = {
        ACCELERATE: base + KMH,
        SLOW_DOWN: base - KMH,
        STEER: base,
        BRAKE: 0.0,
    }
    for action, want in expected.items():
        got = float(desired_speed(jnp.int32(action), ego, params))
        assert got == pytest.approx(want, abs=1e-6), (mode, action, got, want)


@pytest.mark.parametrize("mode", ["measured", "setpoint"])
def test_desired_speed_slow_down_clamps_at_zero(static, mode):
    params = EnvParams(setpoint_mode=mode)
    ego = _ego(static, v=0.1, v_setpoint=0.1)
    assert float(desired_speed(jnp.int32(SLOW_DOWN), ego, params)) == 0.0
    ego = _ego(static, v=0.0, v_setpoint=0.0)
    assert float(desired_speed(jnp.int32(SLOW_DOWN), ego, params)) == 0.0
    assert float(desired_speed(jnp.int32(ACCELERATE), ego, params)) == pytest.approx(KMH)


def test_setpoint_mode_accumulates_over_steps(static):
    """'setpoint' adds 1 km/h to the previous setpoint; 'measured' to the measured speed."""
    for mode in ("setpoint", "measured"):
        params = EnvParams(setpoint_mode=mode)
        ego = _ego(static)
        for _ in range(3):
            before = ego
            ego = ego_step(ego, jnp.int32(ACCELERATE), params)
            base = before.v_setpoint if mode == "setpoint" else before.v
            assert float(ego.v_setpoint) == pytest.approx(float(base) + KMH, rel=1e-6)
        if mode == "setpoint":
            assert float(ego.v_setpoint) == pytest.approx(3 * KMH, rel=1e-5)
        else:  # the car lags its setpoint: measured mode never runs far ahead of v
            assert float(ego.v_setpoint) < float(ego.v) + KMH + 1e-6
            assert float(ego.v_setpoint) < 3 * KMH - 0.1
        # slow_down then steer from there: -1 km/h, then hold.
        slowed = ego_step(ego, jnp.int32(SLOW_DOWN), params)
        base = ego.v_setpoint if mode == "setpoint" else ego.v
        assert float(slowed.v_setpoint) == pytest.approx(float(base) - KMH, rel=1e-5, abs=1e-6)
        held = ego_step(slowed, jnp.int32(STEER), params)
        base = slowed.v_setpoint if mode == "setpoint" else slowed.v
        assert float(held.v_setpoint) == pytest.approx(float(base), rel=1e-6)


def test_pid_proportional_only_with_first_error(params, static):
    ego = _ego(static, v=2.0)
    v_d = jnp.float32(2.1)  # error 0.1 m/s = 0.36 km/h
    u, errors, count = pid_step(v_d, ego, params)
    e = 0.1 * 3.6
    assert float(u) == pytest.approx(params.pid_kp * e, rel=1e-5)  # no I, no D yet
    assert int(count) == 1
    assert float(errors[-1]) == pytest.approx(e, rel=1e-5)
    np.testing.assert_array_equal(np.asarray(errors[:-1]), 0.0)


def test_pid_integral_and_derivative_from_two_errors(static):
    params = EnvParams(pid_kd=0.01)  # exercise the D term too
    e0 = 0.5
    errs = np.zeros(static.pid_window, np.float32)
    errs[-1] = e0
    ego = _ego(static, v=2.0, errors=errs, count=1)
    v_d = jnp.float32(2.1)
    u, errors, count = pid_step(v_d, ego, params)
    e = 0.1 * 3.6
    dt = params.dt
    want = params.pid_kp * e + params.pid_ki * (e0 + e) * dt + params.pid_kd * (e - e0) / dt
    assert float(u) == pytest.approx(want, rel=1e-5)
    assert int(count) == 2
    np.testing.assert_allclose(np.asarray(errors[-2:]), [e0, e], rtol=1e-6)


def test_pid_integral_window_is_last_ten_errors(params, static):
    k = static.pid_window
    assert k == 10
    errs = np.arange(1, k + 1, dtype=np.float32) * -0.1  # -0.1 … -1.0 km/h, oldest first
    ego = _ego(static, v=2.0, errors=errs, count=k)
    e = 0.2 * 3.6
    u, errors, count = pid_step(jnp.float32(2.2), ego, params)
    window = [*errs[1:], e]  # the oldest error (-0.1) drops out
    want = params.pid_kp * e + params.pid_ki * sum(window) * params.dt
    assert float(u) == pytest.approx(want, rel=1e-5)
    np.testing.assert_allclose(np.asarray(errors), window, rtol=1e-6)
    assert int(count) == k  # count saturates at the window size


def test_pid_output_is_clipped(params, static):
    ego = _ego(static, v=0.0)
    u, _, _ = pid_step(jnp.float32(10.0), ego, params)  # e = 36 km/h
    assert float(u) == 1.0
    ego = _ego(static, v=10.0)
    u, _, _ = pid_step(jnp.float32(0.0), ego, params)
    assert float(u) == -1.0


@pytest.mark.parametrize(
    ("u", "throttle", "brake"),
    [
        (0.0, 0.0, 0.0),
        (0.5, 0.5, 0.0),
        (0.75, 0.75, 0.0),
        (0.9, 0.75, 0.0),
        (1.0, 0.75, 0.0),
        (-0.2, 0.0, 0.2),
        (-0.3, 0.0, 0.3),
        (-0.9, 0.0, 0.3),
        (-1.0, 0.0, 0.3),
    ],
)
def test_throttle_brake_limits(params, u, throttle, brake):
    t, b = throttle_brake(jnp.float32(u), params)
    assert float(t) == pytest.approx(throttle, abs=1e-7)
    assert float(b) == pytest.approx(brake, abs=1e-7)


def test_plant_step_formula(params, static):
    ego = _ego(static, v=2.0, accel=1.0, s=10.0)
    out = plant_step(ego, jnp.float32(0.5), jnp.float32(0.0), params)
    a_cmd = 0.5 * params.accel_throttle - params.rolling_resistance  # moving: 1.9
    a = 1.0 + (a_cmd - 1.0) * params.dt / params.accel_lag
    v = 2.0 + a * params.dt
    assert float(out.accel) == pytest.approx(a, rel=1e-6)
    assert float(out.v) == pytest.approx(v, rel=1e-6)
    assert float(out.s) == pytest.approx(10.0 + v * params.dt, rel=1e-6)
    # Braking: a_cmd = -brake*A_brk - c_roll.
    out = plant_step(ego, jnp.float32(0.0), jnp.float32(0.3), params)
    a_cmd = -0.3 * params.accel_brake - params.rolling_resistance
    a = 1.0 + (a_cmd - 1.0) * params.dt / params.accel_lag
    assert float(out.accel) == pytest.approx(a, rel=1e-6)
    assert float(out.v) == pytest.approx(2.0 + a * params.dt, rel=1e-6)


def test_plant_no_rolling_resistance_at_rest(params, static):
    ego = _ego(static, v=0.0, accel=0.0)
    out = plant_step(ego, jnp.float32(0.0), jnp.float32(0.0), params)
    assert float(out.v) == 0.0
    assert float(out.accel) == 0.0
    assert float(out.s) == pytest.approx(5.0)


def test_brake_action_bypasses_pid(params, static):
    errs = np.linspace(-1, 1, static.pid_window).astype(np.float32)
    ego = _ego(static, v=3.0, v_setpoint=3.0, errors=errs, count=7)
    out = ego_step(ego, jnp.int32(BRAKE), params)
    np.testing.assert_array_equal(np.asarray(out.pid_errors), errs)
    assert int(out.pid_count) == 7
    assert float(out.v_setpoint) == 0.0
    a_cmd = -1.0 * params.accel_brake - params.rolling_resistance  # brake 1, not brake_max
    a = a_cmd * params.dt / params.accel_lag
    assert float(out.accel) == pytest.approx(a, rel=1e-6)
    assert float(out.v) == pytest.approx(3.0 + a * params.dt, rel=1e-6)


# --- 6. jit vs eager, batched ------------------------------------------------
#
# ``import drqn_jax`` turns off FMA contraction in XLA:CPU (drqn_jax.determinism),
# so jitted and eager steps round ``a + b * c`` alike and agree bitwise, and a
# batched step equals the unbatched one.


def _assert_tree_bitwise_equal(a, b):
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb, strict=True):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(x, y)


def _varied_egos(static, n: int) -> EgoState:
    rng = np.random.default_rng(7)
    k = static.pid_window
    return EgoState(
        s=jnp.asarray(rng.uniform(0, 200, n), jnp.float32),
        v=jnp.asarray(rng.uniform(0, 13, n), jnp.float32),
        accel=jnp.asarray(rng.uniform(-8, 3, n), jnp.float32),
        v_setpoint=jnp.asarray(rng.uniform(0, 13, n), jnp.float32),
        pid_errors=jnp.asarray(rng.uniform(-5, 5, (n, k)), jnp.float32),
        pid_count=jnp.asarray(rng.integers(0, k + 1, n), jnp.int32),
    )


def _row(tree, i: int):
    return jax.tree.map(lambda x: x[i], tree)


@pytest.fixture(scope="module")
def jitted_step():
    return jax.jit(ego_step)


def test_ego_step_jit_matches_eager_scalar(params, static, jitted_step):
    egos = _varied_egos(static, 4)
    for i in range(4):
        ego = _row(egos, i)
        for action in (ACCELERATE, SLOW_DOWN, BRAKE, STEER):
            a = jnp.int32(action)
            eager = ego_step(ego, a, params)
            jitted = jitted_step(ego, a, params)
            _assert_tree_bitwise_equal(jitted, eager)
            _assert_tree_bitwise_equal(jitted_step(ego, a, params), jitted)  # deterministic
            assert eager.v.shape == () and jitted.v.shape == ()
            assert jitted.pid_errors.shape == (static.pid_window,)


def test_ego_step_vmapped_batch(params, static, jitted_step):
    n = 8
    egos = _varied_egos(static, n)
    actions = jnp.arange(n, dtype=jnp.int32) % 4
    batched = jax.vmap(ego_step, in_axes=(0, 0, None))
    eager = batched(egos, actions, params)
    jitted = jax.jit(batched)(egos, actions, params)
    assert jitted.v.shape == (n,) and eager.v.shape == (n,)
    assert jitted.pid_errors.shape == (n, static.pid_window)
    _assert_tree_bitwise_equal(jitted, eager)
    for i in range(n):
        ego, a = _row(egos, i), actions[i]
        # A row of the batch is bitwise the unbatched step, eager and jitted alike.
        _assert_tree_bitwise_equal(_row(eager, i), ego_step(ego, a, params))
        _assert_tree_bitwise_equal(_row(jitted, i), jitted_step(ego, a, params))
    assert np.all(np.asarray(jitted.v) >= 0.0)
    assert np.all(np.isfinite(np.asarray(jitted.s)))
