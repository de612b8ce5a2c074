"""The ego vehicle: action -> setpoint -> PID -> plant (paper §IV-B, Alg. 1; SPEC §2).
One environment per call; ``vmap`` batches."""

import jax
import jax.numpy as jnp

from drqn_jax.env.params import CHANGE_PER_DECISION, SETPOINT_PREVIOUS, EnvParams, StaticEnvParams
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, EgoState

MS_TO_KMH = 3.6


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
    """() float32 setpoint v_d (m/s) for an () int32 action (SPEC §2): base ± 1 km/h,
    base (steer) or 0 (brake); base is the measured speed or the previous setpoint
    (``setpoint_mode``)."""
    base = jnp.where(params.setpoint_mode == SETPOINT_PREVIOUS, ego.v_setpoint, ego.v)
    step = params.setpoint_step
    up = base + step
    down = jnp.maximum(base - step, 0.0)
    v_d = jnp.where(action == ACCELERATE, up, jnp.where(action == SLOW_DOWN, down, base))
    return jnp.where(action == BRAKE, 0.0, v_d).astype(jnp.float32)


def pid_step(
    v_d: jax.Array, ego: EgoState, params: EnvParams
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """CARLA's longitudinal PID on the speed error in km/h (SPEC §2): ``u = clip(Kp·e +
    Ki·Σe·dt + Kd·Δe/dt, -1, 1)`` over the last K errors (I and D 0 until two are stored).
    Returns u () float32, the new (K,) error buffer and count."""
    e = (v_d - ego.v) * MS_TO_KMH
    errors = jnp.concatenate([ego.pid_errors[1:], e[None]])
    count = jnp.minimum(ego.pid_count + 1, errors.shape[0])
    enough = count >= 2
    de = jnp.where(enough, (errors[-1] - errors[-2]) * (1.0 / params.dt), 0.0)
    ie = jnp.where(enough, jnp.sum(errors) * params.dt, 0.0)
    u = params.pid_kp * e + params.pid_kd * de + params.pid_ki * ie
    return jnp.clip(u, -1.0, 1.0).astype(jnp.float32), errors, count


def throttle_brake(u: jax.Array, params: EnvParams) -> tuple[jax.Array, jax.Array]:
    """``(throttle, brake)`` from the PID output (paper eq. for T_p, B_p; CARLA's limits)."""
    throttle = jnp.minimum(jnp.maximum(u, 0.0), params.throttle_max)
    brake = jnp.minimum(jnp.maximum(-u, 0.0), params.brake_max)
    return throttle, brake


def plant_step(ego: EgoState, throttle: jax.Array, brake: jax.Array, params: EnvParams) -> EgoState:
    """One step of the first-order-lag longitudinal plant (SPEC §2); at rest no deceleration
    (a ≥ 0 at v = 0), so it starts again without undoing a lagged braking force."""
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


def ego_step(
    ego: EgoState, action: jax.Array, params: EnvParams, hold: jax.Array | None = None
) -> EgoState:
    """One tick: setpoint, PID, plant. ``brake`` is CARLA's emergency stop: throttle 0,
    brake 1, the PID's history untouched. ``hold`` (() bool, a decision's later ticks
    under ``setpoint_change = "decision"``) keeps the previous setpoint instead."""
    v_d = desired_speed(action, ego, params)
    if hold is not None:
        kept = jnp.where(action == BRAKE, 0.0, ego.v_setpoint).astype(jnp.float32)
        v_d = jnp.where(hold & (params.setpoint_change == CHANGE_PER_DECISION), kept, v_d)
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
