"""Collision and time to collision (paper §IV-B "Reward Function"; SPEC §5).

The ego is an axis-aligned box (its heading is always +x along the route);
a pedestrian is a disc. :func:`box_disc_overlap` is the one geometric test
used for the collision, for pedestrians that stop short of the car, and for
the TTC projection.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from drqn_jax.env.params import EnvParams, StaticEnvParams
from drqn_jax.env.road_map import lane_centre_y
from drqn_jax.env.state import EgoState, PedestrianState

__all__ = ["box_disc_overlap", "collision", "ego_box", "time_to_collision"]


def ego_box(s: jax.Array, params: EnvParams, inflate: float | jax.Array = 0.0):
    """Centre (..., 2) and half extents (2,) of the ego footprint at arc length ``s``."""
    s = jnp.asarray(s, jnp.float32)
    centre = jnp.stack([s, jnp.broadcast_to(lane_centre_y(params), s.shape)], axis=-1)
    half = jnp.stack([0.5 * params.ego_length + inflate, 0.5 * params.ego_width + inflate])
    return centre, half.astype(jnp.float32)


def box_disc_overlap(
    box_centre: jax.Array, box_half: jax.Array, disc_centre: jax.Array, radius: jax.Array
) -> jax.Array:
    """Whether axis-aligned boxes and discs overlap (strictly: touching is not overlap).

    Args:
        box_centre: (..., 2); box_half: (2,); disc_centre: (..., 2) broadcastable
            with ``box_centre``; radius: () or broadcastable.
    Returns:
        (...,) bool.
    """
    d = jnp.maximum(jnp.abs(disc_centre - box_centre) - box_half, 0.0)
    return jnp.sum(d * d, axis=-1) < radius * radius


def collision(ego: EgoState, peds: PedestrianState, params: EnvParams) -> jax.Array:
    """() bool: the ego's box overlaps any pedestrian's disc."""
    centre, half = ego_box(ego.s, params)
    return jnp.any(box_disc_overlap(centre, half, peds.position, params.ped_radius))


def time_to_collision(
    ego: EgoState, peds: PedestrianState, params: EnvParams, static: StaticEnvParams
) -> jax.Array:
    """TTC (s): first sample time at which box and a disc overlap (SPEC §5).

    The ego is projected along its route at its current speed, every
    pedestrian at its current velocity, at ``t = 0, ttc_step, …, ttc_horizon``;
    the result is the minimum over pedestrians, ``inf`` if none overlaps or
    the ego is stopped (``v < stopped_speed``).

    Returns:
        () float32 in ``{0, ttc_step, …, ttc_horizon} ∪ {inf}``.
    """
    t = jnp.arange(static.ttc_samples, dtype=jnp.float32) * static.ttc_step  # (K,)
    centre, half = ego_box(ego.s + ego.v * t, params)  # (K, 2)
    ped = peds.position[None] + peds.velocity[None] * t[:, None, None]  # (K, P, 2)
    hit = box_disc_overlap(centre[:, None], half, ped, params.ped_radius)  # (K, P)
    any_hit = jnp.any(hit, axis=1)  # (K,)
    first = jnp.argmax(any_hit)
    ttc = jnp.where(jnp.any(any_hit), t[first], jnp.inf)
    return jnp.where(ego.v < params.stopped_speed, jnp.inf, ttc).astype(jnp.float32)
