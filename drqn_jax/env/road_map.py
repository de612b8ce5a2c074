"""The map (SPEC §1): main road, sidewalks, unsignalized intersections, crosswalks, defined
once by :func:`semantic_class`. x runs along the ego's road, y to its left; a boundary
point belongs to the walkway side."""

import jax
import jax.numpy as jnp

from drqn_jax.env.params import EnvParams, StaticEnvParams

OFF_ROAD, WALKWAY, CROSSING_AREA, ROAD = 0, 1, 2, 3


def intersection_centres(params: EnvParams, static: StaticEnvParams) -> jax.Array:
    """(I,) float32 x of each cross street's centre line (SPEC §1: 50, 100, 150 m)."""
    k = jnp.arange(static.num_intersections, dtype=jnp.float32)
    return params.first_intersection_x + k * params.intersection_spacing


def lane_centre_y(params: EnvParams) -> jax.Array:
    """() float32, y of the ego's (right) lane centre: ``-lane_width / 2``."""
    return -0.5 * jnp.asarray(params.lane_width, jnp.float32)


def crosswalk_centres(params: EnvParams, static: StaticEnvParams) -> jax.Array:
    """(2I,) float32 x of the crosswalks across the main road, both sides of each street."""
    xc = intersection_centres(params, static)
    off = 0.5 * params.cross_street_width + 0.5 * params.crosswalk_width
    return jnp.concatenate([xc - off, xc + off])


def semantic_class(xy: jax.Array, params: EnvParams, static: StaticEnvParams) -> jax.Array:
    """(...,) int32 class of (..., 2) points: 0 off-road, 1 walkway, 2 crossing, 3 road."""
    x, y = xy[..., 0], xy[..., 1]
    ay = jnp.abs(y)
    centres = intersection_centres(params, static)  # (I,)
    half_street = 0.5 * params.cross_street_width
    # Distance to the nearest cross street, a min written out (exact, and it fuses).
    dx_min = jnp.abs(x - centres[0])
    for k in range(1, static.num_intersections):
        dx_min = jnp.minimum(dx_min, jnp.abs(x - centres[k]))
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
    cls = jnp.where(on_main | in_street, ROAD, OFF_ROAD)
    cls = jnp.where(on_side | street_sidewalk, WALKWAY, cls)
    cls = jnp.where(main_crosswalk | street_crosswalk, CROSSING_AREA, cls)
    return cls.astype(jnp.int32)
