"""Pedestrians (paper §V-D; SPEC §3): spawned on a main sidewalk with a behaviour and
``NUM_WAYPOINTS`` waypoints, walked straight to the next, replaced when far or done."""

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap

from drqn_jax.env.collision import box_disc_overlap, ego_box, squared_length
from drqn_jax.env.params import PED_YIELD, EnvParams, StaticEnvParams
from drqn_jax.env.road_map import crosswalk_centres, intersection_centres
from drqn_jax.env.state import (
    CROSSING,
    JAYWALKING,
    NUM_WAYPOINTS,
    SIDEWALK,
    EgoState,
    PedestrianState,
)
from drqn_jax.programs import cached_program
from drqn_jax.pytree import tree_where

_FAR = 1e6  # stands in for ±infinity in segment bounds
_EDGE = 1e-3  # m kept between a sidewalk pedestrian's end point and a cross street


def sidewalk_x(
    u: jax.Array, x_lo: jax.Array, x_hi: jax.Array, params: EnvParams, static: StaticEnvParams
) -> jax.Array:
    """(...,) uniforms in [0, 1) -> x uniform over [x_lo, x_hi) minus the cross streets."""
    starts = intersection_centres(params, static) - 0.5 * params.cross_street_width  # (I,)
    width = params.cross_street_width

    def compress(x):
        return x - jnp.sum(jnp.clip(x[..., None] - starts, 0.0, width), axis=-1)

    lo, hi = compress(jnp.asarray(x_lo)), compress(jnp.asarray(x_hi))
    x = lo + u * (hi - lo)
    for k in range(static.num_intersections):  # intersections are sorted along x
        x = jnp.where(x >= starts[k], x + width, x)
    return x


def _segment_bounds(
    x: jax.Array, params: EnvParams, static: StaticEnvParams
) -> tuple[jax.Array, jax.Array]:
    """Ends of the sidewalk segment (between cross streets) that contains ``x``."""
    xc = intersection_centres(params, static)
    half = 0.5 * params.cross_street_width
    ends = xc + half  # a segment may start where a street ends
    starts = xc - half
    lo = jnp.max(jnp.where(ends <= x[..., None], ends, -_FAR), axis=-1)
    hi = jnp.min(jnp.where(starts >= x[..., None], starts, _FAR), axis=-1)
    return lo + _EDGE, hi - _EDGE


def spawn_pedestrians(
    key: jax.Array, x_lo: jax.Array, x_hi: jax.Array, params: EnvParams, static: StaticEnvParams
) -> PedestrianState:
    """P new pedestrians, standing, on the main sidewalks with x in [x_lo, x_hi) (SPEC §3)."""
    num = static.num_pedestrians
    # Drawn flat: the bits of shape (8, P), a rank fewer to compile under vmap.
    u = jax.random.uniform(key, (8 * num,), dtype=jnp.float32).reshape(8, num)
    u_x, u_side, u_y, u_speed, u_behaviour, u_angle, u_len, u_dir = u

    x = sidewalk_x(u_x, x_lo, x_hi, params, static)
    side = jnp.where(u_side < 0.5, 1.0, -1.0)  # +1: left sidewalk, -1: right sidewalk
    r = params.ped_radius
    inner = jnp.minimum(params.lane_width + r, params.lane_width + 0.5 * params.sidewalk_width)
    outer = jnp.maximum(
        params.lane_width + params.sidewalk_width - r,
        params.lane_width + 0.5 * params.sidewalk_width,
    )
    y = side * (inner + u_y * (outer - inner))
    speed = params.ped_speed_min + u_speed * (params.ped_speed_max - params.ped_speed_min)
    behaviour = jnp.where(
        u_behaviour < params.prob_crossing,
        CROSSING,
        jnp.where(
            u_behaviour < params.prob_crossing + params.prob_jaywalking, JAYWALKING, SIDEWALK
        ),
    ).astype(jnp.int32)
    direction = jnp.where(u_dir < 0.5, 1.0, -1.0)
    walk_on = params.walk_on_min + u_len * (params.walk_on_max - params.walk_on_min)

    # crossing: nearest crosswalk, across, walk on.
    cw = crosswalk_centres(params, static)  # (2I,)
    x_cw = cw[jnp.argmin(jnp.abs(x[:, None] - cw), axis=1)]
    crossing_path = jnp.stack(
        [
            jnp.stack([x_cw, y], -1),
            jnp.stack([x_cw, -y], -1),
            jnp.stack([x_cw + direction * walk_on, -y], -1),
        ],
        axis=1,
    )
    # jaywalking: across at an angle, walk on.
    angle = params.jaywalk_angle_min + u_angle * (
        params.jaywalk_angle_max - params.jaywalk_angle_min
    )
    x_far = x + 2.0 * jnp.abs(y) * jnp.cos(angle) / jnp.sin(angle)
    jay_end = jnp.stack([x_far + direction * walk_on, -y], -1)
    jay_path = jnp.stack([jnp.stack([x_far, -y], -1), jay_end, jay_end], axis=1)
    # sidewalk: along the sidewalk segment, never past a cross street.
    length = params.sidewalk_walk_min + u_len * (
        params.sidewalk_walk_max - params.sidewalk_walk_min
    )
    seg_lo, seg_hi = _segment_bounds(x, params, static)
    x_end = jnp.clip(x + direction * length, seg_lo, seg_hi)
    side_end = jnp.stack([x_end, y], -1)
    side_path = jnp.stack([side_end] * NUM_WAYPOINTS, axis=1)

    b = behaviour[:, None, None]
    waypoints = jnp.where(
        b == CROSSING, crossing_path, jnp.where(b == JAYWALKING, jay_path, side_path)
    )
    position = jnp.stack([x, y], -1)
    first = waypoints[:, 0] - position
    heading = jnp.arctan2(first[:, 1], first[:, 0])
    return PedestrianState(
        position=position.astype(jnp.float32),
        velocity=jnp.zeros((num, 2), jnp.float32),
        speed=jnp.zeros((num,), jnp.float32),
        heading=heading.astype(jnp.float32),
        desired_speed=speed.astype(jnp.float32),
        behaviour=behaviour,
        waypoints=waypoints.astype(jnp.float32),
        waypoint_index=jnp.zeros((num,), jnp.int32),
        waited=jnp.zeros((num,), jnp.float32),
        visible=jnp.ones((num,), bool),
    )


#: ``fold_in`` data of the key that draws a step's occlusion (the step's key draws spawns).
OCCLUSION_STREAM = 1


def occlusion_mask(key: jax.Array, params: EnvParams, static: StaticEnvParams) -> jax.Array:
    """(P,) bool ``visible``: each hidden with probability ``occlusion_prob`` per step."""
    num = static.num_pedestrians

    def draw() -> jax.Array:
        u = jax.random.uniform(jax.random.fold_in(key, OCCLUSION_STREAM), (num,), jnp.float32)
        return u >= params.occlusion_prob

    # At 0 every u passes: skip the draw (a real branch unless the probability is batched).
    return jax.lax.cond(params.occlusion_prob > 0.0, draw, lambda: jnp.ones((num,), bool))


def _waits_at_kerb(
    peds: PedestrianState, new_position: jax.Array, ego: EgoState, params: EnvParams
) -> jax.Array:
    """(P,) bool: gap acceptance holds at the kerb, the ego within ``wait_distance``/``_time``."""
    stepping_on = (jnp.abs(peds.position[:, 1]) >= params.lane_width) & (
        jnp.abs(new_position[:, 1]) < params.lane_width
    )
    gap = peds.position[:, 0] - (ego.s + 0.5 * params.ego_length)  # ahead of the front bumper
    not_passed = gap > -params.ego_length
    arrive = gap / jnp.maximum(ego.v, 1e-3)
    close = (gap < params.wait_distance) | (arrive < params.wait_time)
    return (params.gap_acceptance == 1) & stepping_on & not_passed & close


def step_pedestrians(peds: PedestrianState, ego: EgoState, params: EnvParams) -> PedestrianState:
    """Walk every pedestrian one step to its next waypoint (SPEC §3); ``"yield"``: stand
    (``ped_wait_max_s`` at most) rather than enter the inflated ego footprint."""
    num_wp = peds.waypoints.shape[-2]
    done = peds.done
    idx = jnp.minimum(peds.waypoint_index, num_wp - 1)
    target = jnp.take_along_axis(peds.waypoints, idx[:, None, None], axis=1)[:, 0]  # (P, 2)
    delta = target - peds.position
    dist = jnp.sqrt(squared_length(delta))
    step = peds.desired_speed * params.dt
    reach = dist <= step
    unit = delta / jnp.where(dist > 0.0, dist, 1.0)[:, None]
    new_position = jnp.where(reach[:, None], target, peds.position + unit * step[:, None])

    centre, half = ego_box(ego.s, params, inflate=params.ped_clearance)
    # Half a step of slack: it waits round(ped_wait_max_s / dt) steps, whatever the rounding.
    patience = params.ped_wait_max_s - 0.5 * params.dt
    patient = (params.ped_behaviour_to_car == PED_YIELD) & (peds.waited < patience)
    blocked = ~done & patient & box_disc_overlap(centre, half, new_position, params.ped_radius)
    moves = ~done & ~blocked & ~_waits_at_kerb(peds, new_position, ego, params)
    position = jnp.where(moves[:, None], new_position, peds.position)
    heading = jnp.where(moves & (dist > 0.0), jnp.arctan2(delta[:, 1], delta[:, 0]), peds.heading)
    return peds.replace(
        position=position,
        velocity=(position - peds.position) * (1.0 / params.dt),
        speed=jnp.where(moves, jnp.where(reach, dist, step), 0.0) * (1.0 / params.dt),
        heading=heading.astype(jnp.float32),
        waypoint_index=peds.waypoint_index + (moves & reach).astype(jnp.int32),
        waited=peds.waited + jnp.where(blocked, params.dt, 0.0).astype(jnp.float32),
    )


def despawn_mask(peds: PedestrianState, ego: EgoState, params: EnvParams) -> jax.Array:
    """(P,) bool: pedestrians to replace: far behind the ego's rear, far ahead, or done."""
    x = peds.position[:, 0]
    rear = ego.s - 0.5 * params.ego_length
    behind = x < rear - params.despawn_behind
    ahead = x > ego.s + params.despawn_ahead
    return behind | ahead | peds.done


#: Under ``vmap`` the envs that respawn draw, ``max(1, N // this)`` per pass (same bits).
RESPAWN_GATHER_SHARE = 32


def respawn_pedestrians(
    key: jax.Array,
    peds: PedestrianState,
    replace: jax.Array,
    x_lo: jax.Array,
    x_hi: jax.Array,
    params: EnvParams,
    static: StaticEnvParams,
) -> PedestrianState:
    """``spawn_pedestrians`` where ``replace`` (P,) is set; skipped where nothing is
    (under ``vmap`` a gather), same bits as drawing in every env."""
    return _respawn(static)(key, peds, replace, x_lo, x_hi, params)


@cached_program
def _respawn(static: StaticEnvParams) -> Callable[..., PedestrianState]:

    def respawn_all(key, peds, replace, x_lo, x_hi, params):
        return tree_where(replace, spawn_pedestrians(key, x_lo, x_hi, params, static), peds)

    @custom_vmap
    def respawn(key, peds, replace, x_lo, x_hi, params):
        args = (key, peds, replace, x_lo, x_hi, params)
        return jax.lax.cond(jnp.any(replace), respawn_all, lambda *_: peds, *args)

    @respawn.def_vmap
    def respawn_batched(num_envs, in_batched, key, peds, replace, x_lo, x_hi, params):
        args = (key, peds, replace, x_lo, x_hi, params)
        in_batched = tuple(in_batched)
        every_env = jax.vmap(respawn_all, jax.tree.map(lambda b: 0 if b else None, in_batched))
        peds, replace = jax.tree.map(
            lambda x, b: x if b else jnp.broadcast_to(x, (num_envs, *x.shape)),
            (peds, replace),
            in_batched[1:3],
        )
        needs = jnp.any(replace, axis=-1)  # (N,)
        count = jnp.sum(needs)
        chunk = max(1, num_envs // RESPAWN_GATHER_SHARE)
        passes = -(-num_envs // chunk)
        # The envs that need a draw first, then out-of-range fill (dropped below).
        (order,) = jnp.nonzero(needs, size=passes * chunk, fill_value=num_envs)

        def one_pass(carry):
            i, out = carry
            idx = jax.lax.dynamic_slice(order, (i * chunk,), (chunk,))
            take = jnp.minimum(idx, num_envs - 1)
            new = every_env(*jax.tree.map(lambda x, b: x[take] if b else x, args, in_batched))
            return i + 1, jax.tree.map(lambda o, n: o.at[idx].set(n, mode="drop"), out, new)

        _, out = jax.lax.while_loop(lambda c: c[0] * chunk < count, one_pass, (0, peds))
        return out, jax.tree.map(lambda _: True, out)

    return respawn
