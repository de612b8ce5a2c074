"""The ego-centred observation grid (paper §IV-B, §V-A; SPEC §4), (45, 30, 4) float32:
occupancy, heading / π, speed, semantic class / 3 (or threat). The nearest pedestrian wins a
cell, so the grid does not depend on XLA's scatter order."""

import jax
import jax.numpy as jnp

from drqn_jax.env.collision import squared_length
from drqn_jax.env.params import (
    SEMANTIC_MAP,
    SEMANTIC_THREAT,
    SPEED_RELATIVE,
    EnvParams,
    StaticEnvParams,
)
from drqn_jax.env.road_map import lane_centre_y, semantic_class
from drqn_jax.env.state import EgoState, PedestrianState
from drqn_jax.pytree import pytree_dataclass

NUM_CHANNELS = 4
CORRIDOR_MARGIN = 0.5  # m; the rule-based agent's default (SPEC §6)
# Per-channel bounds of the grid values (occupancy, heading, speed, semantics).
GRID_LOW = (0.0, -1.0, 0.0, 0.0)
GRID_HIGH = (1.0, 1.0, float("inf"), 1.0)


@pytree_dataclass
class GridInputs:
    """The ego's ``s``, ``v`` () and the pedestrians' fields the grid is rasterised from:
    6P + 2 floats and P flags a replay stores instead of 5400 grid floats."""

    s: jax.Array
    v: jax.Array
    position: jax.Array
    velocity: jax.Array
    heading: jax.Array
    speed: jax.Array
    visible: jax.Array

    @classmethod
    def of(cls, ego: EgoState, peds: PedestrianState) -> "GridInputs":
        fields = ("position", "velocity", "heading", "speed", "visible")
        return cls(s=ego.s, v=ego.v, **{name: getattr(peds, name) for name in fields})

    @classmethod
    def empty(cls, num_pedestrians: int) -> "GridInputs":
        p, f32 = num_pedestrians, jnp.float32
        return cls(
            s=jnp.zeros((), f32),
            v=jnp.zeros((), f32),
            position=jnp.zeros((p, 2), f32),
            velocity=jnp.zeros((p, 2), f32),
            heading=jnp.zeros((p,), f32),
            speed=jnp.zeros((p,), f32),
            visible=jnp.zeros((p,), bool),
        )


def cell_centres(
    ego: EgoState | GridInputs, params: EnvParams, static: StaticEnvParams
) -> jax.Array:
    """(rows, cols, 2) float32 world coordinates of every cell centre (ego: its ``s`` is used)."""
    rows = jnp.arange(static.grid_rows, dtype=jnp.float32)
    cols = jnp.arange(static.grid_cols, dtype=jnp.float32)
    x = ego.s + static.grid_x_min + (rows + 0.5) * static.cell_size
    y = lane_centre_y(params) + static.grid_y_min + (cols + 0.5) * static.cell_size
    return jnp.stack(jnp.broadcast_arrays(x[:, None], y[None, :]), axis=-1)


def grid_cell_index(
    position: jax.Array, ego: EgoState | GridInputs, params: EnvParams, static: StaticEnvParams
) -> tuple[jax.Array, jax.Array]:
    """(P,) int32 flat cell index of (P, 2) positions (``rows * cols`` outside), and inside."""
    rel_x = position[:, 0] - ego.s - static.grid_x_min
    rel_y = position[:, 1] - lane_centre_y(params) - static.grid_y_min
    row = jnp.floor(rel_x * (1.0 / static.cell_size))
    col = jnp.floor(rel_y * (1.0 / static.cell_size))
    inside = (row >= 0) & (row < static.grid_rows) & (col >= 0) & (col < static.grid_cols)
    size = static.grid_rows * static.grid_cols
    flat = jnp.where(inside, row * static.grid_cols + col, size)  # out of range, never negative
    return flat.astype(jnp.int32), inside


def _nearest_wins(flat: jax.Array, dist2: jax.Array, size: int) -> jax.Array:
    """``flat`` (P,) with ``size`` where a nearer pedestrian (ties: lower index) wins the cell."""
    num = flat.shape[0]
    order = jnp.arange(num)
    # beats[j, i]: j shares i's cell and is nearer
    beats = (flat[:, None] == flat[None, :]) & (
        (dist2[:, None] < dist2[None, :])
        | ((dist2[:, None] == dist2[None, :]) & (order[:, None] < order[None, :]))
    )
    # OR-ed row by row: a reduction over a short axis vectorises poorly on XLA:CPU.
    loses = beats[0]
    for j in range(1, num):
        loses = loses | beats[j]
    return jnp.where(loses, size, flat)


def times_between(
    a: jax.Array, b: jax.Array, low: jax.Array | float, high: jax.Array | float
) -> tuple[jax.Array, jax.Array]:
    """Elementwise (start, end) of the times t with low ≤ a + b·t ≤ high (maybe empty)."""
    moving = b != 0.0
    rate = jnp.where(moving, b, 1.0)
    t_low, t_high = (low - a) / rate, (high - a) / rate
    inside = (a >= low) & (a <= high)
    always = jnp.where(inside, -jnp.inf, jnp.inf)
    start = jnp.where(moving, jnp.minimum(t_low, t_high), always)
    end = jnp.where(moving, jnp.maximum(t_low, t_high), -always)
    return start, end


def corridor_times(g: GridInputs, params: EnvParams, margin: float) -> tuple[jax.Array, ...]:
    """(P,) each pedestrian's distance ``ahead`` of the ego's bumper (m), whether it is in the
    ego's corridor (half width + its radius + ``margin``) across the lane now, and (start, end)
    of the times it is in the corridor, walking on, not yet passed by the bumper at speed v."""
    half = 0.5 * params.ego_width + params.ped_radius + margin
    offset = g.position[:, 1] - lane_centre_y(params)
    ahead = g.position[:, 0] - (g.s + 0.5 * params.ego_length)
    lat = times_between(offset, g.velocity[:, 1], -half, half)
    unpassed = times_between(ahead, g.velocity[:, 0] - g.v, -params.ped_radius, jnp.inf)
    start, end = jnp.maximum(lat[0], unpassed[0]), jnp.minimum(lat[1], unpassed[1])
    return ahead, jnp.abs(offset) <= half, start, end


def threat(g: GridInputs, params: EnvParams, static: StaticEnvParams) -> jax.Array:
    """(P,) float32 1 − t / ``ttc_horizon``, 0 beyond it or never: t ≥ 0 the first time each
    pedestrian is in the rule-based agent's default corridor (:func:`corridor_times`), a feature
    of what one frame shows (``semantic_channel = "threat"``, not the paper's)."""
    _, _, start, end = corridor_times(g, params, CORRIDOR_MARGIN)
    start = jnp.maximum(start, 0.0)
    t = jnp.where(start <= end, start, jnp.inf)
    return jnp.clip(1.0 - t * (1.0 / static.ttc_horizon), 0.0, 1.0)


def rasterize_grid(
    ego: EgoState, peds: PedestrianState, params: EnvParams, static: StaticEnvParams
) -> jax.Array:
    """(rows, cols, 4) float32 observation grid of the pedestrians around the ego."""
    return rasterize(GridInputs.of(ego, peds), params, static)


def rasterize(g: GridInputs, params: EnvParams, static: StaticEnvParams) -> jax.Array:
    """:func:`rasterize_grid` from a :class:`GridInputs` record: (rows, cols, 4) float32."""
    size = static.grid_rows * static.grid_cols
    flat, _ = grid_cell_index(g.position, g, params, static)
    flat = jnp.where(g.visible, flat, size)  # occluded: dropped, and never blocks a cell
    rel = g.position - jnp.stack([g.s, lane_centre_y(params)])
    flat = _nearest_wins(flat, squared_length(rel), size)

    # Wrap pi to -pi (the ego heads 0); no multiply-add: XLA may fuse it into an FMA.
    heading = jnp.where(g.heading >= jnp.pi, g.heading - 2.0 * jnp.pi, g.heading)
    speed_ped = g.speed * (1.0 / params.speed_norm_pedestrian)
    rel_v = g.velocity - jnp.stack([g.v, jnp.zeros_like(g.v)])
    speed_rel = jnp.sqrt(squared_length(rel_v)) * (1.0 / params.speed_norm_relative)
    speed = jnp.where(params.speed_channel == SPEED_RELATIVE, speed_rel, speed_ped)
    use_map = params.semantic_channel == SEMANTIC_MAP
    semantic = semantic_class(g.position, params, static).astype(jnp.float32) / 3.0
    is_threat = params.semantic_channel == SEMANTIC_THREAT
    semantic = jnp.where(is_threat, threat(g, params, static), semantic)
    values = jnp.stack([jnp.ones_like(heading), heading / jnp.pi, speed, semantic], axis=-1)

    def with_map(values):
        dense = semantic_class(cell_centres(g, params, static), params, static) / 3.0
        dense = dense.reshape(size).astype(jnp.float32)
        cell = dense.at[jnp.minimum(flat, size - 1)].get()
        base = jnp.zeros((size, NUM_CHANNELS), jnp.float32).at[:, 3].set(dense)
        return base, values.at[:, 3].set(cell)

    def without_map(values):
        return jnp.zeros((size, NUM_CHANNELS), jnp.float32), values

    base, values = jax.lax.cond(use_map, with_map, without_map, values)
    grid = base.at[flat].set(values.astype(jnp.float32), mode="drop", unique_indices=False)
    return grid.reshape(static.grid_rows, static.grid_cols, NUM_CHANNELS)
