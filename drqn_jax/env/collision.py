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

__all__ = ["box_disc_overlap", "collision", "ego_box", "squared_length", "time_to_collision"]


def ego_box(s: jax.Array, params: EnvParams, inflate: float | jax.Array = 0.0):
    """Centre (..., 2) and half extents (2,) of the ego footprint at arc length ``s``."""
    s = jnp.asarray(s, jnp.float32)
    centre = jnp.stack([s, jnp.broadcast_to(lane_centre_y(params), s.shape)], axis=-1)
    half = jnp.stack([0.5 * params.ego_length + inflate, 0.5 * params.ego_width + inflate])
    return centre, half.astype(jnp.float32)


def squared_length(v: jax.Array) -> jax.Array:
    """(..., 2) vectors -> (...,) ``x² + y²``.

    Written out rather than as a sum over the last axis: the same bits (a sum of
    two), but XLA:CPU fuses it with its neighbours instead of running a
    separate reduction kernel per use.
    """
    return v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1]


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
    # Components written out: a reduction over a minor axis of size 2 vectorises poorly.
    dx = jnp.maximum(jnp.abs(disc_centre[..., 0] - box_centre[..., 0]) - box_half[0], 0.0)
    dy = jnp.maximum(jnp.abs(disc_centre[..., 1] - box_centre[..., 1]) - box_half[1], 0.0)
    return dx * dx + dy * dy < radius * radius


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
    t = jnp.arange(static.ttc_samples, dtype=jnp.float32)[:, None] * static.ttc_step  # (K, 1)
    # Pedestrians relative to the ego's box centre, in the ego's moving frame: (K, P).
    _, half = ego_box(ego.s, params)
    rel_x = peds.position[:, 0] - ego.s + (peds.velocity[:, 0] - ego.v) * t
    rel_y = peds.position[:, 1] - lane_centre_y(params) + peds.velocity[:, 1] * t
    hit = box_disc_overlap(
        jnp.zeros(2, jnp.float32), half, jnp.stack([rel_x, rel_y], -1), params.ped_radius
    )
    # The first sample time with any overlap, as one min-reduction (no argmax).
    ttc = jnp.min(jnp.where(hit, t, jnp.inf))
    return jnp.where(ego.v < params.stopped_speed, jnp.inf, ttc).astype(jnp.float32)
