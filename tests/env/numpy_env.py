"""``UrbanPedestrians-v0`` in plain NumPy: one environment at a time, no JAX.

This is the simulator of ``drqn_jax.env`` (SPEC §1–5) written as a user would
write it without JAX: NumPy arrays over the P pedestrians, ordinary Python
control flow, one environment per call. It is the tests' **oracle**:
``tests/env/test_numpy_oracle.py`` drives it and the JAX env with the same
actions and the same random numbers and requires equal trajectories
(:func:`numpy_steps_per_s` times it standalone, the plain loop a user would
otherwise run).

Every function is named after, and computes what, its JAX counterpart does,
in float32 and in the order of operations XLA compiles (a division by a
constant or by a broadcast value becomes a product with the reciprocal; short
sums run left to right), so that the two agree to the last bit wherever the
arithmetic is IEEE's:

=========================  ===========================================================
here                       JAX
=========================  ===========================================================
``intersection_centres``,  ``drqn_jax.env.road_map`` (map and semantic classes, §1)
``lane_centre_y``,
``crosswalk_centres``,
``semantic_class``
``initial_ego``,           ``drqn_jax.env.ego`` (action → setpoint → PID → plant, §2)
``desired_speed``,
``pid_step``,
``throttle_brake``,
``plant_step``, ``ego_step``
``sidewalk_x``,            ``drqn_jax.env.pedestrians`` (spawn, paths, walking,
``spawn_pedestrians``,     despawn, §3)
``step_pedestrians``,
``despawn_mask``,
``respawn_pedestrians``
``cell_centres``,          ``drqn_jax.env.grid`` (the 45 × 30 × 4 grid, §4)
``grid_cell_index``,
``rasterize_grid``
``ego_box``,               ``drqn_jax.env.collision`` (§5)
``box_disc_overlap``,
``collision``,
``time_to_collision``
``speed_reward``,          ``drqn_jax.env.collision`` (§5)
``reward``
``NumpyUrbanPedestrians``  ``drqn_jax.env.urban.UrbanPedestrians`` (reset, step with
                           same-step auto-reset, ``step_env``, ``advance``)
=========================  ===========================================================

Randomness. The JAX env takes exactly two arrays from the key of a ``reset``
or a ``step``: ``jax.random.uniform(key, (8, P), float32)`` inside
``spawn_pedestrians`` (rows: x, side, y, desired speed, behaviour, jaywalking
angle, path length, direction) and ``uniform(fold_in(key, 1), (P,))`` inside
``occlusion_mask`` (which pedestrians the grid shows); it computes the first in
a step only where a pedestrian is replaced, and the second only when
``occlusion_prob > 0`` (at 0 it shows every pedestrian). A step uses the first
to replace the pedestrians that are gone, or, when the episode ends, to spawn
the next episode's P pedestrians (the same arrays feed ``info["final_state"]``).
Here those uniforms are an explicit ``draws`` argument of NUM_DRAWS = 9 rows
(the 8 spawn rows, then the occlusion row): :func:`jax_draws` returns the very
arrays the JAX env draws from a key (so both envs can be compared),
:func:`numpy_draws` draws them from an ``np.random.Generator`` for standalone
use.

Transcendental functions are the one place where bits may differ: XLA's CPU
``cos``, ``sin`` and ``atan2`` call glibc's ``cosf``, ``sinf`` and ``atan2f``
(errors up to 0.56, 0.56 and 1.3 ulp); here they are NumPy's float64 functions
rounded to float32, which agree in most cases and otherwise differ by one ulp
(jaywalking waypoints; headings).

The state and observation are small dataclasses with the field names of
``drqn_jax.env.state`` holding NumPy float32/int32 values. From ``drqn_jax``
this module takes only the parameter classes and the codes (actions,
behaviours, semantic classes); the simulation itself is NumPy.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from typing import Any

import numpy as np

from drqn_jax.env.ego import MS_TO_KMH
from drqn_jax.env.grid import NUM_CHANNELS
from drqn_jax.env.params import (
    COLLISION_AUTHORS,
    PED_YIELD,
    SEMANTIC_MAP,
    SEMANTIC_PEDESTRIAN,
    SETPOINT_PREVIOUS,
    SPEED_RELATIVE,
    TTC_COLLISION,
    EnvParams,
    StaticEnvParams,
)
from drqn_jax.env.road_map import CROSSING_AREA, OFF_ROAD, ROAD, WALKWAY
from drqn_jax.env.state import (
    ACCELERATE,
    BRAKE,
    CROSSING,
    JAYWALKING,
    NO_ACTION,
    NUM_ACTIONS,
    NUM_WAYPOINTS,
    SIDEWALK,
    SLOW_DOWN,
)

__all__ = [
    "NUM_DRAWS",
    "NUM_SPAWN_DRAWS",
    "EgoState",
    "EnvState",
    "NumpyUrbanPedestrians",
    "Observation",
    "PedestrianState",
    "jax_draws",
    "numpy_draws",
    "numpy_steps_per_s",
]

NUM_SPAWN_DRAWS = 8  # uniforms per pedestrian per spawn (see the module docstring)
NUM_DRAWS = NUM_SPAWN_DRAWS + 1  # and one for its occlusion
_FAR = 1e6  # stands in for ±infinity in segment bounds
_EDGE = 1e-3  # m kept between a sidewalk pedestrian's end point and a cross street

F32 = np.float32
Array = np.ndarray
# XLA compiles ``x / c`` as ``x * (1 / c)`` for a constant c, and ``x / broadcast(d)`` as
# ``x * broadcast(1 / d)``; this module writes those products, so that the bits agree.
_THIRD = F32(1.0 / 3.0)
_INV_PI = F32(1.0 / np.pi)


# --- state -------------------------------------------------------------------
@dataclasses.dataclass
class EgoState:
    """The ego (``drqn_jax.env.state.EgoState``): scalars float32, ``pid_errors`` (K,)."""

    s: np.float32
    v: np.float32
    accel: np.float32
    v_setpoint: np.float32
    pid_errors: Array
    pid_count: np.int32


@dataclasses.dataclass
class PedestrianState:
    """The P pedestrians (``drqn_jax.env.state.PedestrianState``), leading axis P."""

    position: Array  # (P, 2) float32
    velocity: Array  # (P, 2) float32
    speed: Array  # (P,) float32
    heading: Array  # (P,) float32
    desired_speed: Array  # (P,) float32
    behaviour: Array  # (P,) int32
    waypoints: Array  # (P, W, 2) float32
    waypoint_index: Array  # (P,) int32
    waited: Array  # (P,) float32, seconds stood yielding to the car
    visible: Array  # (P,) bool

    @property
    def done(self) -> Array:
        return self.waypoint_index >= self.waypoints.shape[-2]


@dataclasses.dataclass
class EnvState:
    """Full state of one environment (``drqn_jax.env.state.EnvState``)."""

    ego: EgoState
    pedestrians: PedestrianState
    last_action: np.int32
    time: np.int32


@dataclasses.dataclass
class Observation:
    """What the agent sees (``drqn_jax.env.state.Observation``)."""

    grid: Array  # (rows, cols, 4) float32
    speed: np.float32
    last_action: np.int32


# --- randomness --------------------------------------------------------------
def numpy_draws(rng: np.random.Generator, static: StaticEnvParams) -> Array:
    """One step's uniforms in [0, 1) from a NumPy generator: (NUM_DRAWS, P) float32."""
    return rng.random((NUM_DRAWS, static.num_pedestrians), dtype=np.float32)


def jax_draws(key: Any, static: StaticEnvParams) -> Array:
    """The uniforms the JAX env draws from ``key`` (test helper; imports JAX).

    ``spawn_pedestrians`` (``reset`` and every ``step``) draws
    ``jax.random.uniform(key, (8, P), float32)`` and ``occlusion_mask``
    ``uniform(fold_in(key, 1), (P,))``; this returns them stacked, (NUM_DRAWS, P).
    ``key`` may be a batch of keys (any leading shape), e.g.
    ``jax.random.split(key, T)``: the result is then (..., NUM_DRAWS, P).
    """
    import jax
    import jax.numpy as jnp

    key = jnp.asarray(key)
    typed = jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
    batch_dims = key.ndim if typed else key.ndim - 1  # a raw uint32 key has shape (2,)
    return np.asarray(_jax_draw_fn(static.num_pedestrians, batch_dims)(key))


@functools.cache
def _jax_draw_fn(num_pedestrians: int, batch_dims: int) -> Any:
    """``jax_draws``' jitted function, built once per shape so that it compiles once."""
    import jax
    import jax.numpy as jnp

    from drqn_jax.env.pedestrians import OCCLUSION_STREAM

    def draw(k: jax.Array) -> jax.Array:
        spawn = jax.random.uniform(k, (NUM_SPAWN_DRAWS, num_pedestrians), dtype=jnp.float32)
        k_occlusion = jax.random.fold_in(k, OCCLUSION_STREAM)
        occlusion = jax.random.uniform(k_occlusion, (1, num_pedestrians), dtype=jnp.float32)
        return jnp.concatenate([spawn, occlusion])

    for _ in range(batch_dims):
        draw = jax.vmap(draw)
    return jax.jit(draw)


# --- road map (drqn_jax.env.road_map) -----------------------------------------
def intersection_centres(params: EnvParams, static: StaticEnvParams) -> Array:
    """(I,) float32 x of each cross street's centre line."""
    k = np.arange(static.num_intersections, dtype=F32)
    return params.first_intersection_x + k * params.intersection_spacing


def lane_centre_y(params: EnvParams) -> np.float32:
    """y of the ego's lane centre, ``-lane_width / 2``."""
    return F32(-0.5 * params.lane_width)


def crosswalk_centres(params: EnvParams, static: StaticEnvParams) -> Array:
    """(2I,) float32 x of the crosswalks across the main road."""
    xc = intersection_centres(params, static)
    off = 0.5 * params.cross_street_width + 0.5 * params.crosswalk_width
    return np.concatenate([xc - off, xc + off])


def semantic_class(xy: Array, params: EnvParams, static: StaticEnvParams) -> Array:
    """(...,) int32 class of points (..., 2): 0 off-road, 1 walkway, 2 crossing, 3 road."""
    x, y = xy[..., 0], xy[..., 1]
    ay = np.abs(y)
    dx_min = np.min(np.abs(x[..., None] - intersection_centres(params, static)), axis=-1)
    half_street = 0.5 * params.cross_street_width
    in_street = dx_min < half_street
    on_main = ay < params.lane_width
    on_side = (ay >= params.lane_width) & (ay <= params.lane_width + params.sidewalk_width)
    main_crosswalk = (
        on_main & (dx_min >= half_street) & (dx_min <= half_street + params.crosswalk_width)
    )
    street_crosswalk = in_street & on_side
    street_sidewalk = (
        (ay > params.lane_width + params.sidewalk_width)
        & (dx_min >= half_street)
        & (dx_min <= half_street + params.sidewalk_width)
    )
    cls = np.where(on_main | in_street, ROAD, OFF_ROAD)
    cls = np.where(on_side | street_sidewalk, WALKWAY, cls)
    cls = np.where(main_crosswalk | street_crosswalk, CROSSING_AREA, cls)
    return cls.astype(np.int32)


# --- ego (drqn_jax.env.ego) ------------------------------------------------------
def initial_ego(params: EnvParams, static: StaticEnvParams) -> EgoState:
    """At rest at ``ego_start_s``, setpoint 0, empty PID history."""
    return EgoState(
        s=F32(params.ego_start_s),
        v=F32(0.0),
        accel=F32(0.0),
        v_setpoint=F32(0.0),
        pid_errors=np.zeros(static.pid_window, F32),
        pid_count=np.int32(0),
    )


def desired_speed(action: int, ego: EgoState, params: EnvParams) -> np.float32:
    """Setpoint v_d (m/s): base ± 1 km/h, base, or 0 for ``brake``."""
    base = ego.v_setpoint if params.setpoint_mode == SETPOINT_PREVIOUS else ego.v
    if action == ACCELERATE:
        return F32(base + params.setpoint_step)
    if action == SLOW_DOWN:
        return F32(max(base - params.setpoint_step, F32(0.0)))
    if action == BRAKE:
        return F32(0.0)
    return F32(base)


def pid_step(
    v_d: np.float32, ego: EgoState, params: EnvParams
) -> tuple[np.float32, Array, np.int32]:
    """CARLA's PID on the error in km/h: ``(u, new error buffer, new count)``."""
    e = F32((v_d - ego.v) * F32(MS_TO_KMH))
    errors = np.append(ego.pid_errors[1:], e)
    count = np.int32(min(ego.pid_count + 1, errors.shape[0]))
    if count >= 2:
        de = (errors[-1] - errors[-2]) * (1.0 / params.dt)
        # Summed left to right, as XLA reduces one unbatched env (np.sum is pairwise).
        ie = np.cumsum(errors)[-1] * params.dt
    else:
        de = ie = F32(0.0)
    u = params.pid_kp * e + params.pid_kd * de + params.pid_ki * ie
    return F32(np.clip(u, -1.0, 1.0)), errors, count


def throttle_brake(u: np.float32, params: EnvParams) -> tuple[np.float32, np.float32]:
    """Pedals from the PID output: ``min(max(±u, 0), limit)``."""
    throttle = F32(min(max(u, F32(0.0)), params.throttle_max))
    brake = F32(min(max(-u, F32(0.0)), params.brake_max))
    return throttle, brake


def plant_step(
    ego: EgoState, throttle: np.float32, brake: np.float32, params: EnvParams
) -> EgoState:
    """First-order-lag longitudinal plant over one step (SPEC §2)."""
    rolling = params.rolling_resistance if ego.v > 0.0 else F32(0.0)
    a_cmd = throttle * params.accel_throttle - brake * params.accel_brake - rolling
    accel = F32(ego.accel + (a_cmd - ego.accel) * (params.dt / params.accel_lag))
    v = F32(np.clip(ego.v + accel * params.dt, F32(0.0), params.max_vehicle_speed))
    if v <= 0.0:
        accel = max(accel, F32(0.0))
    s = F32(ego.s + v * params.dt)
    return dataclasses.replace(ego, s=s, v=v, accel=accel)


def ego_step(ego: EgoState, action: int, params: EnvParams) -> EgoState:
    """Setpoint, PID (or the emergency stop, which keeps the PID history), plant."""
    v_d = desired_speed(action, ego, params)
    if action == BRAKE:
        ego = dataclasses.replace(ego, v_setpoint=v_d)
        return plant_step(ego, F32(0.0), F32(1.0), params)
    u, errors, count = pid_step(v_d, ego, params)
    throttle, brake = throttle_brake(u, params)
    ego = dataclasses.replace(ego, v_setpoint=v_d, pid_errors=errors, pid_count=count)
    return plant_step(ego, throttle, brake, params)


# --- collision (drqn_jax.env.collision) --------------------------------------------
def ego_box(s: np.float32, params: EnvParams, inflate: Any = 0.0) -> tuple[Array, Array]:
    """Centre (2,) and half extents (2,) of the ego footprint at arc length ``s``."""
    centre = np.array([s, lane_centre_y(params)], F32)
    half = np.array(
        [0.5 * params.ego_length + inflate, 0.5 * params.ego_width + inflate], dtype=F32
    )
    return centre, half


def box_disc_overlap(box_centre: Array, box_half: Array, disc_centre: Array, radius: Any) -> Array:
    """Strict overlap of an axis-aligned box and discs (..., 2): (...,) bool."""
    dx = np.maximum(np.abs(disc_centre[..., 0] - box_centre[..., 0]) - box_half[0], F32(0.0))
    dy = np.maximum(np.abs(disc_centre[..., 1] - box_centre[..., 1]) - box_half[1], F32(0.0))
    return dx * dx + dy * dy < radius * radius


def in_authors_zone(rel_x: Array, y: Array, params: EnvParams) -> Array:
    """The authors' test: in the ego's lane, ``rel_x`` (along, from the ego centre) within
    −back … front and ``y`` within the half width of the lane centre."""
    return (
        (y >= -params.lane_width)
        & (y <= 0.0)
        & (rel_x >= -params.authors_zone_back)
        & (rel_x <= params.authors_zone_front)
        & (np.abs(y - lane_centre_y(params)) <= params.authors_zone_half_width)
    )


def classify_hits(ego: EgoState, peds: PedestrianState, params: EnvParams) -> tuple[bool, bool]:
    """``(collision, struck_while_stopped)``: a pedestrian meets the ``collision_model``
    test (box-disc contact, or the authors' zone in the ego's lane) while the ego
    moves, or while it stands."""
    if params.collision_model == COLLISION_AUTHORS:
        hit = in_authors_zone(peds.position[:, 0] - ego.s, peds.position[:, 1], params)
    else:
        centre, half = ego_box(ego.s, params)
        hit = box_disc_overlap(centre, half, peds.position, params.ped_radius)
    moving = bool(ego.v >= params.stopped_speed)
    return bool(hit.any()) and moving, bool(hit.any()) and not moving


def time_to_collision(
    ego: EgoState, peds: PedestrianState, params: EnvParams, static: StaticEnvParams
) -> np.float32:
    """First sample time in {0, step, …, horizon} at which ``reward_ttc_test``'s test holds (a
    box–disc overlap, or the authors' zone); inf if none or stopped."""
    if ego.v < params.stopped_speed:
        return F32(np.inf)
    t = np.arange(static.ttc_samples, dtype=F32)[:, None] * F32(static.ttc_step)  # (K, 1)
    if params.reward_ttc_test == TTC_COLLISION and params.collision_model == COLLISION_AUTHORS:
        x = peds.position[:, 0] - ego.s + (peds.velocity[:, 0] - ego.v) * t  # (K, P)
        y = peds.position[:, 1] + peds.velocity[:, 1] * t
        hit = in_authors_zone(x, y, params).any(axis=1)
        return F32(t[np.argmax(hit), 0]) if hit.any() else F32(np.inf)
    _, half = ego_box(ego.s, params)
    rel_x = peds.position[:, 0] - ego.s + (peds.velocity[:, 0] - ego.v) * t
    rel_y = peds.position[:, 1] - lane_centre_y(params) + peds.velocity[:, 1] * t
    hit = box_disc_overlap(
        np.zeros(2, F32), half, np.stack([rel_x, rel_y], -1), params.ped_radius
    ).any(axis=1)
    return F32(t[np.argmax(hit), 0]) if hit.any() else F32(np.inf)


# --- reward (drqn_jax.env.collision) ------------------------------------------
def speed_reward(v: np.float32, params: EnvParams) -> np.float32:
    """r_v: ``1 − (v_ref − v)/v_ref``, ``reward_stopped`` when stopped, overspeed above v_ref."""
    if v < params.stopped_speed:
        return F32(params.reward_stopped)
    if v > params.v_ref:
        return F32(params.reward_overspeed)
    return F32(1.0 - (params.v_ref - v) * (1.0 / params.v_ref))


def reward(collided: bool, ttc: np.float32, v: np.float32, params: EnvParams) -> np.float32:
    """First matching row: collision, near collision (TTC ≤ threshold), speed."""
    if collided:
        return F32(params.reward_collision)
    if ttc <= params.ttc_threshold:
        return F32(params.reward_near_collision_weight * (ttc - params.ttc_threshold))
    return speed_reward(v, params)


# --- pedestrians (drqn_jax.env.pedestrians) -----------------------------------------
def sidewalk_x(
    u: Array, x_lo: np.float32, x_hi: np.float32, params: EnvParams, static: StaticEnvParams
) -> Array:
    """Uniforms → x uniform over the main-sidewalk stretches in [x_lo, x_hi), streets cut out."""
    starts = intersection_centres(params, static) - 0.5 * params.cross_street_width
    width = params.cross_street_width

    def compress(x: np.float32) -> np.float32:
        cut = np.clip(x - starts, F32(0.0), width)
        return x - np.cumsum(cut)[-1]  # left to right, as XLA sums

    lo, hi = compress(x_lo), compress(x_hi)
    x = lo + u * (hi - lo)
    for start in starts:  # intersections are sorted along x
        x = np.where(x >= start, x + width, x)
    return x


def _segment_bounds(x: Array, params: EnvParams, static: StaticEnvParams) -> tuple[Array, Array]:
    """Ends of the sidewalk segment (between cross streets) that contains each ``x``."""
    xc = intersection_centres(params, static)
    half = 0.5 * params.cross_street_width
    ends, starts = xc + half, xc - half
    lo = np.max(np.where(ends <= x[:, None], ends, F32(-_FAR)), axis=-1)
    hi = np.min(np.where(starts >= x[:, None], starts, F32(_FAR)), axis=-1)
    return lo + F32(_EDGE), hi - F32(_EDGE)


def spawn_pedestrians(
    draws: Array, x_lo: np.float32, x_hi: np.float32, params: EnvParams, static: StaticEnvParams
) -> PedestrianState:
    """P new pedestrians on the main sidewalks with x in [x_lo, x_hi) (SPEC §3).

    ``draws``: (NUM_DRAWS, P) uniforms (:func:`jax_draws`); the first 8 rows are
    the array the JAX function draws from its key.
    """
    num = static.num_pedestrians
    u_x, u_side, u_y, u_speed, u_behaviour, u_angle, u_len, u_dir = draws[:NUM_SPAWN_DRAWS]
    one = F32(1.0)

    x = sidewalk_x(u_x, x_lo, x_hi, params, static)
    side = np.where(u_side < 0.5, one, -one)
    r = params.ped_radius
    inner = np.minimum(params.lane_width + r, params.lane_width + 0.5 * params.sidewalk_width)
    outer = np.maximum(
        params.lane_width + params.sidewalk_width - r,
        params.lane_width + 0.5 * params.sidewalk_width,
    )
    y = side * (inner + u_y * (outer - inner))
    speed = params.ped_speed_min + u_speed * (params.ped_speed_max - params.ped_speed_min)
    behaviour = np.where(
        u_behaviour < params.prob_crossing,
        CROSSING,
        np.where(u_behaviour < params.prob_crossing + params.prob_jaywalking, JAYWALKING, SIDEWALK),
    ).astype(np.int32)
    direction = np.where(u_dir < 0.5, one, -one)
    walk_on = params.walk_on_min + u_len * (params.walk_on_max - params.walk_on_min)

    # crossing: nearest crosswalk, across, walk on.
    cw = crosswalk_centres(params, static)
    x_cw = cw[np.argmin(np.abs(x[:, None] - cw), axis=1)]
    crossing_path = np.stack(
        [
            np.stack([x_cw, y], -1),
            np.stack([x_cw, -y], -1),
            np.stack([x_cw + direction * walk_on, -y], -1),
        ],
        axis=1,
    )
    # jaywalking: across at an angle, walk on.
    angle = (
        params.jaywalk_angle_min + u_angle * (params.jaywalk_angle_max - params.jaywalk_angle_min)
    ).astype(np.float64)
    x_far = x + 2.0 * np.abs(y) * np.cos(angle).astype(F32) / np.sin(angle).astype(F32)
    jay_end = np.stack([x_far + direction * walk_on, -y], -1)
    jay_path = np.stack([np.stack([x_far, -y], -1), jay_end, jay_end], axis=1)
    # sidewalk: along the sidewalk segment, never past a cross street.
    length = params.sidewalk_walk_min + u_len * (
        params.sidewalk_walk_max - params.sidewalk_walk_min
    )
    seg_lo, seg_hi = _segment_bounds(x, params, static)
    x_end = np.clip(x + direction * length, seg_lo, seg_hi)
    side_path = np.repeat(np.stack([x_end, y], -1)[:, None], NUM_WAYPOINTS, axis=1)

    b = behaviour[:, None, None]
    waypoints = np.where(
        b == CROSSING, crossing_path, np.where(b == JAYWALKING, jay_path, side_path)
    )
    position = np.stack([x, y], -1)
    first = (waypoints[:, 0] - position).astype(np.float64)
    return PedestrianState(
        position=position,
        velocity=np.zeros((num, 2), F32),
        speed=np.zeros(num, F32),
        heading=np.arctan2(first[:, 1], first[:, 0]).astype(F32),
        desired_speed=speed,
        behaviour=behaviour,
        waypoints=waypoints,
        waypoint_index=np.zeros(num, np.int32),
        waited=np.zeros(num, F32),
        visible=np.ones(num, bool),
    )


def occlusion_mask(draws: Array, params: EnvParams) -> Array:
    """(P,) bool: the pedestrians the grid shows; the last row of ``draws`` (:func:`jax_draws`)."""
    return draws[NUM_SPAWN_DRAWS] >= params.occlusion_prob


def _waits_at_kerb(
    peds: PedestrianState, new_position: Array, ego: EgoState, params: EnvParams
) -> Array:
    """(P,) bool: gap acceptance (off by default) holds a pedestrian at the kerb."""
    if params.gap_acceptance != 1:
        return np.zeros(peds.position.shape[0], bool)
    stepping_on = (np.abs(peds.position[:, 1]) >= params.lane_width) & (
        np.abs(new_position[:, 1]) < params.lane_width
    )
    gap = peds.position[:, 0] - (ego.s + 0.5 * params.ego_length)
    not_passed = gap > -params.ego_length
    arrive = gap * (F32(1.0) / max(ego.v, F32(1e-3)))  # XLA: x / d as x * (1 / d)
    close = (gap < params.wait_distance) | (arrive < params.wait_time)
    return stepping_on & not_passed & close


def step_pedestrians(peds: PedestrianState, ego: EgoState, params: EnvParams) -> PedestrianState:
    """Walk every pedestrian one step towards its next waypoint; with
    ``ped_behaviour_to_car = "yield"`` not into the car, for at most ``ped_wait_max_s``."""
    num = peds.position.shape[0]
    idx = np.minimum(peds.waypoint_index, peds.waypoints.shape[1] - 1)
    target = peds.waypoints[np.arange(num), idx]  # (P, 2)
    delta = target - peds.position
    dist = np.sqrt(delta[:, 0] * delta[:, 0] + delta[:, 1] * delta[:, 1])
    step = peds.desired_speed * params.dt
    reach = dist <= step
    inv_dist = F32(1.0) / np.where(dist > 0.0, dist, F32(1.0))  # XLA: x / d as x * (1 / d)
    unit = delta * inv_dist[:, None]
    new_position = np.where(reach[:, None], target, peds.position + unit * step[:, None])

    centre, half = ego_box(ego.s, params, inflate=params.ped_clearance)
    patience = params.ped_wait_max_s - F32(0.5) * params.dt
    patient = (params.ped_behaviour_to_car == PED_YIELD) & (peds.waited < patience)
    blocked = box_disc_overlap(centre, half, new_position, params.ped_radius)
    blocked &= ~peds.done & patient
    moves = ~peds.done & ~blocked & ~_waits_at_kerb(peds, new_position, ego, params)
    position = np.where(moves[:, None], new_position, peds.position)
    turn = moves & (dist > 0.0)
    heading = peds.heading.copy()
    d = delta[turn].astype(np.float64)
    heading[turn] = np.arctan2(d[:, 1], d[:, 0])
    inv_dt = F32(1.0 / params.dt)
    return dataclasses.replace(
        peds,
        position=position,
        velocity=(position - peds.position) * inv_dt,
        speed=np.where(moves, np.where(reach, dist, step), F32(0.0)) * inv_dt,
        heading=heading,
        waypoint_index=peds.waypoint_index + (moves & reach).astype(np.int32),
        waited=(peds.waited + np.where(blocked, params.dt, F32(0.0))).astype(F32),
    )


def despawn_mask(peds: PedestrianState, ego: EgoState, params: EnvParams) -> Array:
    """(P,) bool: far behind the ego's rear, far ahead, or done."""
    x = peds.position[:, 0]
    rear = ego.s - 0.5 * params.ego_length
    return (x < rear - params.despawn_behind) | (x > ego.s + params.despawn_ahead) | peds.done


def respawn_pedestrians(
    draws: Array,
    peds: PedestrianState,
    replace: Array,
    x_lo: np.float32,
    x_hi: np.float32,
    params: EnvParams,
    static: StaticEnvParams,
) -> PedestrianState:
    """Replace the pedestrians flagged in ``replace`` (P,) by new ones in [x_lo, x_hi)."""
    if not replace.any():
        return peds
    fresh = spawn_pedestrians(draws, x_lo, x_hi, params, static)
    fields = {}
    for f in dataclasses.fields(PedestrianState):
        new, old = getattr(fresh, f.name), getattr(peds, f.name)
        mask = replace.reshape(replace.shape + (1,) * (old.ndim - 1))
        fields[f.name] = np.where(mask, new, old)
    return PedestrianState(**fields)


# --- grid (drqn_jax.env.grid) -----------------------------------------------------
def cell_centres(s: np.float32, params: EnvParams, static: StaticEnvParams) -> Array:
    """(rows, cols, 2) float32 world coordinates of every cell centre."""
    rows = np.arange(static.grid_rows, dtype=F32)
    cols = np.arange(static.grid_cols, dtype=F32)
    x = s + F32(static.grid_x_min) + (rows + F32(0.5)) * F32(static.cell_size)
    y = lane_centre_y(params) + F32(static.grid_y_min) + (cols + F32(0.5)) * F32(static.cell_size)
    return np.stack(np.broadcast_arrays(x[:, None], y[None, :]), axis=-1)


def grid_cell_index(
    position: Array, s: np.float32, params: EnvParams, static: StaticEnvParams
) -> tuple[Array, Array]:
    """(P,) flat cell index ``row * cols + col`` (``rows * cols`` outside) and (P,) inside."""
    inv_cell = F32(1.0 / static.cell_size)
    rel_x = position[:, 0] - s - F32(static.grid_x_min)
    rel_y = position[:, 1] - lane_centre_y(params) - F32(static.grid_y_min)
    row = np.floor(rel_x * inv_cell)
    col = np.floor(rel_y * inv_cell)
    inside = (row >= 0) & (row < static.grid_rows) & (col >= 0) & (col < static.grid_cols)
    size = static.grid_rows * static.grid_cols
    flat = np.where(inside, row * F32(static.grid_cols) + col, F32(size))
    return flat.astype(np.int32), inside


def _nearest_wins(flat: Array, dist2: Array, size: int) -> Array:
    """Push every pedestrian that loses its cell to a nearer one (ties: lower index) out."""
    order = np.arange(flat.shape[0])
    same = flat[:, None] == flat[None, :]
    nearer = (dist2[None, :] < dist2[:, None]) | (
        (dist2[None, :] == dist2[:, None]) & (order[None, :] < order[:, None])
    )
    return np.where(np.any(same & nearer, axis=1), size, flat)


def rasterize_grid(
    ego: EgoState, peds: PedestrianState, params: EnvParams, static: StaticEnvParams
) -> Array:
    """The (rows, cols, 4) float32 observation grid (SPEC §4)."""
    size = static.grid_rows * static.grid_cols
    flat, _ = grid_cell_index(peds.position, ego.s, params, static)
    flat = np.where(peds.visible, flat, size)
    rel = peds.position - np.array([ego.s, lane_centre_y(params)], F32)
    flat = _nearest_wins(flat, rel[:, 0] * rel[:, 0] + rel[:, 1] * rel[:, 1], size)
    keep = flat < size
    flat = flat[keep]

    pi = F32(np.pi)
    heading = peds.heading[keep]
    heading = np.where(heading >= pi, heading - F32(2.0 * np.pi), heading)
    if params.speed_channel == SPEED_RELATIVE:
        rel_v = peds.velocity[keep] - np.array([ego.v, 0.0], F32)
        speed_sq = rel_v[:, 0] * rel_v[:, 0] + rel_v[:, 1] * rel_v[:, 1]
        speed = np.sqrt(speed_sq) * F32(1.0 / params.speed_norm_relative)
    else:
        speed = peds.speed[keep] * F32(1.0 / params.speed_norm_pedestrian)

    if params.semantic_channel not in (SEMANTIC_PEDESTRIAN, SEMANTIC_MAP):
        raise NotImplementedError("the oracle has the pedestrian and map semantic channels")
    grid = np.zeros((size, NUM_CHANNELS), F32)
    if params.semantic_channel == SEMANTIC_MAP:
        dense = semantic_class(cell_centres(ego.s, params, static), params, static)
        grid[:, 3] = dense.reshape(size).astype(F32) * _THIRD
        semantic = grid[flat, 3]
    else:
        semantic = semantic_class(peds.position[keep], params, static).astype(F32) * _THIRD
    grid[flat, 0] = 1.0
    grid[flat, 1] = heading * _INV_PI
    grid[flat, 2] = speed
    grid[flat, 3] = semantic
    return grid.reshape(static.grid_rows, static.grid_cols, NUM_CHANNELS)


# --- the environment (drqn_jax.env.urban) ---------------------------------------------
def _scalar_params(params: EnvParams) -> EnvParams:
    """``params`` with NumPy scalars for fields (arithmetic on them is faster than on 0-d arrays).

    ``EnvParams`` stores validated 0-d float32 / int32 arrays; the copy is built
    without re-running that validation, which would turn the scalars back into arrays.
    """
    scalar = object.__new__(EnvParams)
    for f in dataclasses.fields(EnvParams):
        value = getattr(params, f.name)
        if np.ndim(value) != 0:
            raise ValueError(f"EnvParams.{f.name}: one environment needs scalar params")
        object.__setattr__(scalar, f.name, np.asarray(value)[()])
    return scalar


StepResult = tuple[Observation, EnvState, np.float32, bool, bool, dict[str, Any]]


class NumpyUrbanPedestrians:
    """``UrbanPedestrians`` for one environment in NumPy, with explicit random draws.

    ``draws`` arguments take a (NUM_DRAWS, P) float32 array of uniforms in
    [0, 1) (:func:`numpy_draws`, :func:`jax_draws`) or an
    ``np.random.Generator`` to draw one from.
    """

    def __init__(
        self, static: StaticEnvParams | None = None, params: EnvParams | None = None
    ) -> None:
        self.static = StaticEnvParams() if static is None else static
        params = EnvParams() if params is None else params
        self.params = _scalar_params(params)

    @property
    def name(self) -> str:
        return "UrbanPedestrians-v0"

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    def _draws(self, draws: Array | np.random.Generator) -> Array:
        if isinstance(draws, np.random.Generator):
            return numpy_draws(draws, self.static)
        draws = np.asarray(draws, F32)
        expected = (NUM_DRAWS, self.static.num_pedestrians)
        if draws.shape != expected:
            raise ValueError(f"draws has shape {draws.shape}, expected {expected}")
        return draws

    def observation(self, state: EnvState) -> Observation:
        """The agent's observation of ``state`` (SPEC §4)."""
        grid = rasterize_grid(state.ego, state.pedestrians, self.params, self.static)
        speed = F32(state.ego.v * F32(1.0 / self.params.v_ref))
        return Observation(grid=grid, speed=speed, last_action=np.int32(state.last_action))

    def _spawn_range(self, s: np.float32, initial: bool) -> tuple[np.float32, np.float32]:
        p = self.params
        if initial:
            return F32(s + p.spawn_initial_min), F32(s + p.spawn_initial_max)
        return F32(s + p.spawn_min), F32(s + p.spawn_max)

    def reset_state(self, draws: Array | np.random.Generator) -> EnvState:
        """A fresh episode: ego at rest at the start, P pedestrians around it."""
        ego = initial_ego(self.params, self.static)
        lo, hi = self._spawn_range(ego.s, initial=True)
        draws = self._draws(draws)
        peds = spawn_pedestrians(draws, lo, hi, self.params, self.static)
        peds.visible = occlusion_mask(draws, self.params)
        return EnvState(
            ego=ego, pedestrians=peds, last_action=np.int32(NO_ACTION), time=np.int32(0)
        )

    def reset(self, draws: Array | np.random.Generator) -> tuple[Observation, EnvState]:
        """``(obs, state)`` of a new episode."""
        state = self.reset_state(draws)
        return self.observation(state), state

    def advance(
        self, state: EnvState, action: int
    ) -> tuple[EnvState, np.float32, bool, bool, dict[str, Any]]:
        """Everything but replacing pedestrians: ego, pedestrians, collision, TTC, reward."""
        p = self.params
        invalid = not 0 <= int(action) < NUM_ACTIONS
        action = min(max(int(action), 0), NUM_ACTIONS - 1)
        ego = ego_step(state.ego, action, p)
        peds = step_pedestrians(state.pedestrians, ego, p)
        collided, struck = classify_hits(ego, peds, p)
        ttc = time_to_collision(ego, peds, p, self.static)
        r = reward(collided, ttc, ego.v, p)
        goal = bool(ego.s >= p.goal_x)
        t = np.int32(state.time + 1)
        terminated = collided or goal
        truncated = bool(t >= self.static.max_steps) and not terminated
        stepped = EnvState(ego=ego, pedestrians=peds, last_action=np.int32(action), time=t)
        info = {
            "collision": collided,
            "struck_while_stopped": struck,
            "goal": goal,
            "ttc": ttc,
            "distance": F32(ego.s - p.ego_start_s),
            "speed": ego.v,
            "time": t,
            "invalid_action": invalid,
        }
        return stepped, r, terminated, truncated, info

    def _next_state(self, draws: Array, stepped: EnvState) -> EnvState:
        """Replace pedestrians far behind, far ahead or done (SPEC §3)."""
        gone = despawn_mask(stepped.pedestrians, stepped.ego, self.params)
        lo, hi = self._spawn_range(stepped.ego.s, initial=False)
        peds = respawn_pedestrians(
            draws, stepped.pedestrians, gone, lo, hi, self.params, self.static
        )
        peds = dataclasses.replace(peds, visible=occlusion_mask(draws, self.params))
        return dataclasses.replace(stepped, pedestrians=peds)

    def step_env(
        self, state: EnvState, action: int, draws: Array | np.random.Generator
    ) -> StepResult:
        """One step without auto-reset; ``draws`` feed the replacement pedestrians."""
        stepped, r, terminated, truncated, info = self.advance(state, action)
        next_state = self._next_state(self._draws(draws), stepped)
        return self.observation(next_state), next_state, r, terminated, truncated, info

    def step(self, state: EnvState, action: int, draws: Array | np.random.Generator) -> StepResult:
        """One step with same-step auto-reset (the JAX env's ``step``).

        While the episode goes on this is ``step_env``; when it ends the state
        and observation are ``reset(draws)``'s, and ``info["final_state"]`` /
        ``info["final_observation"]`` hold what ``step_env`` would have returned.
        """
        draws = self._draws(draws)
        stepped, r, terminated, truncated, info = self.advance(state, action)
        final = self._next_state(draws, stepped)
        final_obs = self.observation(final)
        if terminated or truncated:
            obs, next_state = self.reset(draws)
        else:
            obs, next_state = final_obs, final
        info = dict(info, final_state=final, final_observation=final_obs)
        return obs, next_state, r, terminated, truncated, info


def numpy_steps_per_s(num_steps: int = 2000, seed: int = 0) -> float:
    """Env steps per second of the NumPy env: one env, random actions, full observation.

    ``UrbanPedestrians-v0`` with default parameters; each step draws its
    action and its uniforms from ``np.random.default_rng(seed)`` and rasterises
    the 45 × 30 × 4 grid; an ended episode resets within the step. The first
    reset is outside the timed loop.
    """
    rng = np.random.default_rng(seed)
    env = NumpyUrbanPedestrians()
    _, state = env.reset(rng)
    start = time.perf_counter()
    random_steps(env, state, num_steps, rng)
    return num_steps / (time.perf_counter() - start)


def random_steps(
    env: NumpyUrbanPedestrians, state: Any, num_steps: int, rng: np.random.Generator
) -> Any:
    """``num_steps`` steps of uniformly random actions drawn from ``rng``; the last state."""
    for action in rng.integers(0, NUM_ACTIONS, num_steps):
        _, state, *_ = env.step(state, action, rng)
    return state
