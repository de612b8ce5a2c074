"""The ego vehicle: high-level action -> setpoint -> PID -> plant (paper §IV-B, Alg. 1; SPEC §2).

* :func:`desired_speed` turns an action into the PID setpoint ``v_d``;
* :func:`pid_step` is CARLA's longitudinal PID (error in km/h, integral over
  the last K errors, derivative of the last two);
* :func:`throttle_brake` maps the PID output u to pedals (the paper's
  "u >= 1" read as u >= 0), or the emergency stop for ``brake``;
* :func:`plant_step` integrates the first-order-lag longitudinal plant.

All functions work on one environment; ``vmap`` batches them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from drqn_jax.env.params import SETPOINT_PREVIOUS, EnvParams, StaticEnvParams
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, EgoState

MS_TO_KMH = 3.6

__all__ = ["desired_speed", "ego_step", "initial_ego", "pid_step", "plant_step", "throttle_brake"]


def initial_ego(params: EnvParams, static: StaticEnvParams) -> EgoState:
    """The ego at rest at ``ego_start_s`` with setpoint 0 and an empty PID history."""
    zero = jnp.zeros((), jnp.float32)
    return EgoState(
        s=jnp.asarray(params.ego_start_s, jnp.float32),
        v=zero,
        accel=zero,
        v_setpoint=zero,
        pid_errors=jnp.zeros((static.pid_window,), jnp.float32),
        pid_count=jnp.zeros((), jnp.int32),
    )


def desired_speed(action: jax.Array, ego: EgoState, params: EnvParams) -> jax.Array:
    """Setpoint v_d (m/s) for an action (SPEC §2).

    accelerate: base + 1 km/h; slow_down: max(base - 1 km/h, 0); steer: base;
    brake: 0. ``base`` is the measured speed (``setpoint_mode = "measured"``)
    or the previous setpoint (``"setpoint"``).

    Args:
        action: () int32 in {0, 1, 2, 3}.
    Returns:
        () float32.
    """
    base = jnp.where(params.setpoint_mode == SETPOINT_PREVIOUS, ego.v_setpoint, ego.v)
    step = params.setpoint_step
    up = base + step
    down = jnp.maximum(base - step, 0.0)
    v_d = jnp.where(action == ACCELERATE, up, jnp.where(action == SLOW_DOWN, down, base))
    return jnp.where(action == BRAKE, 0.0, v_d).astype(jnp.float32)


def pid_step(
    v_d: jax.Array, ego: EgoState, params: EnvParams
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """CARLA's longitudinal PID on the speed error in km/h.

    ``u = clip(Kp·e + Ki·Σe·dt + Kd·Δe/dt, -1, 1)`` over the last K errors;
    the integral and derivative are 0 until two errors are stored.

    Returns:
        u: () float32 in [-1, 1]; the new (K,) error buffer; the new count.
    """
    e = (v_d - ego.v) * MS_TO_KMH
    errors = jnp.concatenate([ego.pid_errors[1:], e[None]])
    count = jnp.minimum(ego.pid_count + 1, errors.shape[0])
    enough = count >= 2
    de = jnp.where(enough, (errors[-1] - errors[-2]) * (1.0 / params.dt), 0.0)
    ie = jnp.where(enough, jnp.sum(errors) * params.dt, 0.0)
    u = params.pid_kp * e + params.pid_kd * de + params.pid_ki * ie
    return jnp.clip(u, -1.0, 1.0).astype(jnp.float32), errors, count


def throttle_brake(u: jax.Array, params: EnvParams) -> tuple[jax.Array, jax.Array]:
    """Pedals from the PID output (paper eq. for T_p, B_p; CARLA's limits).

    Returns:
        throttle ``min(max(u, 0), throttle_max)`` and brake ``min(max(-u, 0), brake_max)``.
    """
    throttle = jnp.minimum(jnp.maximum(u, 0.0), params.throttle_max)
    brake = jnp.minimum(jnp.maximum(-u, 0.0), params.brake_max)
    return throttle, brake


def plant_step(ego: EgoState, throttle: jax.Array, brake: jax.Array, params: EnvParams) -> EgoState:
    """Integrate the longitudinal plant over one step (SPEC §2).

    ``a_cmd = throttle·A_thr − brake·A_brk − c_roll·[v > 0]``;
    ``a ← a + (a_cmd − a)·dt/τ``; ``v ← clip(v + a·dt, 0, v_max)``;
    ``s ← s + v·dt``. A vehicle at rest carries no deceleration (a ≥ 0 when
    v = 0), so it starts again without first undoing a lagged braking force.
    """
    moving = ego.v > 0.0
    a_cmd = (
        throttle * params.accel_throttle
        - brake * params.accel_brake
        - jnp.where(moving, params.rolling_resistance, 0.0)
    )
    accel = ego.accel + (a_cmd - ego.accel) * (params.dt / params.accel_lag)
    v = jnp.clip(ego.v + accel * params.dt, 0.0, params.max_vehicle_speed)
    accel = jnp.where(v <= 0.0, jnp.maximum(accel, 0.0), accel)
    s = ego.s + v * params.dt
    return ego.replace(
        s=s.astype(jnp.float32), v=v.astype(jnp.float32), accel=accel.astype(jnp.float32)
    )


def ego_step(ego: EgoState, action: jax.Array, params: EnvParams) -> EgoState:
    """One decision step of the ego: setpoint, PID (or emergency stop), plant.

    ``brake`` bypasses the PID (throttle 0, brake 1, setpoint 0) and leaves
    its error history untouched, as CARLA's emergency stop does.
    """
    v_d = desired_speed(action, ego, params)
    u, errors, count = pid_step(v_d, ego, params)
    throttle, brake = throttle_brake(u, params)
    is_brake = action == BRAKE
    throttle = jnp.where(is_brake, 0.0, throttle)
    brake = jnp.where(is_brake, 1.0, brake)
    ego = ego.replace(
        v_setpoint=v_d,
        pid_errors=jnp.where(is_brake, ego.pid_errors, errors),
        pid_count=jnp.where(is_brake, ego.pid_count, count),
    )
    return plant_step(ego, throttle, brake, params)
