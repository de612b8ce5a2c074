"""Collision, TTC and the reward (paper §IV-B; SPEC §5): the ego an axis-aligned box,
pedestrians discs; the reward is ``r_c`` on a collision, else ``w (TTC − 3)`` for
``TTC ≤ 3 s``, else the speed reward ``r_v``, in [−10, 1] by default."""

import jax
import jax.numpy as jnp

from drqn_jax.env.params import COLLISION_AUTHORS, TTC_COLLISION, EnvParams, StaticEnvParams
from drqn_jax.env.road_map import lane_centre_y
from drqn_jax.env.state import EgoState, PedestrianState


def ego_box(
    s: jax.Array, params: EnvParams, inflate: float | jax.Array = 0.0
) -> tuple[jax.Array, jax.Array]:
    """Centre (..., 2) and half extents (2,) of the ego footprint at arc length ``s``."""
    s = jnp.asarray(s, jnp.float32)
    centre = jnp.stack([s, jnp.broadcast_to(lane_centre_y(params), s.shape)], axis=-1)
    half = jnp.stack([0.5 * params.ego_length + inflate, 0.5 * params.ego_width + inflate])
    return centre, half.astype(jnp.float32)


def squared_length(v: jax.Array) -> jax.Array:
    """(..., 2) vectors -> (...,) ``x² + y²``, written out so XLA:CPU fuses it (no reduction)."""
    return v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1]


def box_squared_distance(box_centre: jax.Array, box_half: jax.Array, point: jax.Array) -> jax.Array:
    """(...,) squared distance from boxes (centre (..., 2), half (2,)) to points; 0 inside."""
    dx = jnp.maximum(jnp.abs(point[..., 0] - box_centre[..., 0]) - box_half[0], 0.0)
    dy = jnp.maximum(jnp.abs(point[..., 1] - box_centre[..., 1]) - box_half[1], 0.0)
    return dx * dx + dy * dy


def box_disc_overlap(
    box_centre: jax.Array, box_half: jax.Array, disc_centre: jax.Array, radius: jax.Array
) -> jax.Array:
    """(...,) bool: boxes and discs overlap strictly (touching is not overlap)."""
    return box_squared_distance(box_centre, box_half, disc_centre) < radius * radius


def collision_region(
    s: jax.Array, params: EnvParams, zone: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Centre (2,) and half extents (2,) of the collision test's box at arc length ``s``:
    the ``authors_zone_*`` box (clipped to the lane) where ``zone``, else the footprint."""
    foot_centre, foot_half = ego_box(s, params)
    lane_y = lane_centre_y(params)
    y_lo = jnp.maximum(-params.lane_width, lane_y - params.authors_zone_half_width)
    y_hi = jnp.minimum(0.0, lane_y + params.authors_zone_half_width)
    zone_centre = jnp.stack(
        [s + 0.5 * (params.authors_zone_front - params.authors_zone_back), 0.5 * (y_lo + y_hi)]
    )
    zone_half = jnp.stack(
        [0.5 * (params.authors_zone_front + params.authors_zone_back), 0.5 * (y_hi - y_lo)]
    )
    return jnp.where(zone, zone_centre, foot_centre), jnp.where(zone, zone_half, foot_half)


def region_hit(d2: jax.Array, zone: jax.Array, params: EnvParams) -> jax.Array:
    """(...,) bool from squared distances to :func:`collision_region`'s box: inside the zone
    (edges in), or a disc overlapping the footprint strictly."""
    return jnp.where(zone, d2 <= 0.0, d2 < params.ped_radius * params.ped_radius)


def collision_test(ego: EgoState, peds: PedestrianState, params: EnvParams) -> jax.Array:
    """(P,) bool ``collision_model`` test (SPEC §5): ``contact``, box overlaps disc;
    ``authors`` (carla-gym ``is_collision``), centre in the ``authors_zone_*`` box, edges in."""
    authors = params.collision_model == COLLISION_AUTHORS
    centre, half = collision_region(ego.s, params, authors)
    return region_hit(box_squared_distance(centre, half, peds.position), authors, params)


def classify_hits(
    ego: EgoState, peds: PedestrianState, params: EnvParams
) -> tuple[jax.Array, jax.Array]:
    """``(hit while moving, hit while stopped)``, () bool each (SPEC §5)."""
    hit = jnp.any(collision_test(ego, peds, params))
    moving = ego.v >= params.stopped_speed
    return hit & moving, hit & ~moving


def time_to_collision(
    ego: EgoState, peds: PedestrianState, params: EnvParams, static: StaticEnvParams
) -> jax.Array:
    """() float32 TTC (s, SPEC §5): the first sampled t <= ``ttc_horizon`` at which ego and
    pedestrians, at constant velocity, meet ``reward_ttc_test``'s test (the footprint
    overlapping a disc, or the collision test); ``inf`` if none or the ego is stopped."""
    t = jnp.arange(static.ttc_samples, dtype=jnp.float32)[:, None] * static.ttc_step  # (K, 1)
    zone = (params.reward_ttc_test == TTC_COLLISION) & (params.collision_model == COLLISION_AUTHORS)
    centre, half = collision_region(ego.s, params, zone)
    # Pedestrians relative to the test box's centre, in the ego's moving frame: (K, P).
    rel_x = peds.position[:, 0] - centre[0] + (peds.velocity[:, 0] - ego.v) * t
    rel_y = peds.position[:, 1] - centre[1] + peds.velocity[:, 1] * t
    d2 = box_squared_distance(jnp.zeros(2, jnp.float32), half, jnp.stack([rel_x, rel_y], -1))
    hit = region_hit(d2, zone, params)
    ttc = jnp.min(jnp.where(hit, t, jnp.inf))
    return jnp.where(ego.v < params.stopped_speed, jnp.inf, ttc).astype(jnp.float32)


def speed_reward(v: jax.Array, params: EnvParams) -> jax.Array:
    """r_v (paper eq. for r_v): () float32 for speed ``v`` (m/s)."""
    normal = 1.0 - (params.v_ref - v) * (1.0 / params.v_ref)
    r = jnp.where(v > params.v_ref, params.reward_overspeed, normal)
    return jnp.where(v < params.stopped_speed, params.reward_stopped, r).astype(jnp.float32)


def reward(collided: jax.Array, ttc: jax.Array, v: jax.Array, params: EnvParams) -> jax.Array:
    """() float32 reward of one step, from the post-step collision flag, TTC (s) and speed."""
    near = ttc <= params.ttc_threshold
    # ttc is inf when there is no near collision: keep inf out of the arithmetic.
    r_nc = params.reward_near_collision_weight * (
        jnp.where(near, ttc, params.ttc_threshold) - params.ttc_threshold
    )
    r = jnp.where(near, r_nc, speed_reward(v, params))
    return jnp.where(collided, params.reward_collision, r).astype(jnp.float32)
