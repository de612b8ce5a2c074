"""Rerun recordings of evaluated episodes (paper §V-E; SPEC §1–5, §8).
:func:`record_episodes` writes :func:`collect_episodes`' episodes to one ``.rrd``
file: a static ``map/``, and per episode ``episode/<i>/`` holds ``world/`` (ego,
pedestrians, headings), ``grid/<channel>`` images, ``speed_kmh``, ``action``,
``q/<action>``, ``reward``, ``ttc`` scalars and an ``events`` text log, on the
``"step"`` timeline (``state.time``). Step t shows the state before decision t;
``reward``/``ttc`` at t come from the step into state t (a collision's −10 sits on
the frame that shows it). Coordinates: :func:`~drqn_jax.interop.rerun_map.to_view`.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Any

import jax
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from drqn_jax.agents.base import Agent
from drqn_jax.env.params import EnvParams
from drqn_jax.env.road_map import OFF_ROAD
from drqn_jax.env.state import ACTIONS
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.env.viewer import (
    ACTION_COLOURS,
    BEHAVIOUR_COLOURS,
    EGO_COLLISION_COLOUR,
    EGO_COLOUR,
    MAP_COLOURS,
    OCCLUDED_ALPHA,
    hud_glyphs,
    hud_text,
)
from drqn_jax.interop.episode_record import EpisodeRecord, collect_episodes
from drqn_jax.interop.rerun_map import log_map, map_extent, to_view
from drqn_jax.networks import Network
from drqn_jax.programs import cached_program

__all__ = [
    "BEHAVIOUR_COLOURS",
    "GRID_CHANNELS",
    "OCCLUDED_ALPHA",
    "STEP_TIMELINE",
    "close_recording",
    "episode_blueprint",
    "hud_labels",
    "open_recording",
    "record_episodes",
    "send_scalars",
    "write_episodes",
]

STEP_TIMELINE = "step"
GRID_CHANNELS = ("occupancy", "heading", "speed", "semantics")  # SPEC §4 channel order


def _steps(values: np.ndarray | range, timeline: str = STEP_TIMELINE) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(timeline, sequence=np.asarray(values, np.int64))]


def send_scalars(
    rec: rr.RecordingStream,
    entity: str,
    steps: np.ndarray,
    values: np.ndarray,
    timeline: str = STEP_TIMELINE,
) -> None:
    """``values`` (E,) at the sequence ``steps`` (E,) of ``timeline``, as float64 scalars."""
    if len(steps):
        rec.send_columns(
            entity,
            indexes=_steps(steps, timeline),
            columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)),
        )


@cached_program
def _hud_program(env: UrbanPedestrians) -> Any:
    """``(states, params) -> glyphs``: jitted :func:`hud_glyphs` over leaves (N, T + 1, ...)."""
    one = partial(hud_glyphs, static=env.static)
    return jax.jit(jax.vmap(jax.vmap(one, in_axes=(0, None)), in_axes=(0, None)))


def hud_labels(record: EpisodeRecord, env: UrbanPedestrians, params: EnvParams) -> np.ndarray:
    """(N, T + 1, 2, L) int32 :func:`hud_glyphs` of every recorded state, one jitted call."""
    return np.asarray(_hud_program(env)(record.state, params))


def _log_episode(
    rec: rr.RecordingStream,
    record: EpisodeRecord,
    i: int,
    env: UrbanPedestrians,
    params: EnvParams,
    hud: np.ndarray,
) -> None:
    """Log episode ``i`` under ``episode/<i>``; ``hud`` (T + 1, 2, L): its HUD glyphs."""
    _log_world(rec, record, i, hud, float(params.ped_radius), env.static.ttc_horizon)
    _log_grid(rec, record, i, env.static.grid_shape)
    _log_series(rec, record, i)
    _log_events(rec, record, i)


def _span(record: EpisodeRecord, i: int) -> tuple[str, int, np.ndarray]:
    """Episode ``i``'s entity root, its length L and its state steps 0…L."""
    n = int(record.length[i])
    return f"episode/{i}", n, np.arange(n + 1)


def _log_world(
    rec: rr.RecordingStream,
    record: EpisodeRecord,
    i: int,
    hud: np.ndarray,
    ped_radius: float,
    heading_s: float,
) -> None:
    """Episode ``i``'s top view: ego, pedestrians, headings (``heading_s`` s of walking)."""
    root, n, states = _span(record, i)
    peds = jax.tree.map(lambda x: x[i, : n + 1], record.state.pedestrians)
    num_peds = peds.position.shape[1]

    collided = np.concatenate([[False], np.cumsum(record.collision[i, :n]) > 0])
    ego_colours = np.where(collided[:, None], EGO_COLLISION_COLOUR, EGO_COLOUR).astype(np.uint8)
    rec.send_columns(
        f"{root}/world/ego",
        indexes=_steps(states),
        columns=rr.Boxes2D.columns(
            centers=to_view(record.ego_centre[i, : n + 1]),
            half_sizes=np.broadcast_to(record.ego_half[i], (n + 1, 2)),
            colors=ego_colours,
            labels=[hud_text(glyphs) for glyphs in hud[: n + 1]],
            draw_order=np.full(n + 1, 3.0, np.float32),
        ),
    )

    behaviour = peds.behaviour.reshape(-1)
    palette = np.array([BEHAVIOUR_COLOURS[k] for k in sorted(BEHAVIOUR_COLOURS)], np.uint8)
    alpha = np.where(peds.visible.reshape(-1), 255, OCCLUDED_ALPHA).astype(np.uint8)
    colours = np.concatenate([palette[behaviour], alpha[:, None]], axis=1)
    positions = to_view(peds.position.reshape(-1, 2))
    lengths = [num_peds] * (n + 1)
    rec.log(f"{root}/world/pedestrians", rr.Points2D.from_fields(show_labels=False), static=True)
    rec.send_columns(
        f"{root}/world/pedestrians",
        indexes=_steps(states),
        columns=rr.Points2D.columns(
            positions=positions,
            colors=colours,
            radii=np.full(len(positions), ped_radius, np.float32),
            class_ids=behaviour.astype(np.uint16),
            draw_order=np.full(len(positions), 4.0, np.float32),
        ).partition(lengths),
    )
    rec.send_columns(
        f"{root}/world/headings",
        indexes=_steps(states),
        columns=rr.Arrows2D.columns(
            origins=positions,
            vectors=to_view(peds.velocity.reshape(-1, 2) * heading_s),
            colors=colours,
            radii=np.full(len(positions), 0.06, np.float32),
        ).partition(lengths),
    )


def _log_grid(
    rec: rr.RecordingStream, record: EpisodeRecord, i: int, grid_shape: tuple[int, int, int]
) -> None:
    """Episode ``i``'s observation grid, one greyscale image per channel."""
    root, n, states = _span(record, i)
    rows, cols, _ = grid_shape
    image_format = rr.components.ImageFormat(
        width=cols, height=rows, color_model="L", channel_datatype="F32"
    )
    grids = np.ascontiguousarray(record.grid[i, : n + 1], np.float32)
    for c, name in enumerate(GRID_CHANNELS):
        entity = f"{root}/grid/{name}"
        rec.log(entity, rr.Image.from_fields(format=image_format), static=True)
        buffers = np.ascontiguousarray(grids[..., c]).reshape(n + 1, -1).view(np.uint8)
        rec.send_columns(entity, indexes=_steps(states), columns=rr.Image.columns(buffer=buffers))


def _log_series(rec: rr.RecordingStream, record: EpisodeRecord, i: int) -> None:
    """Episode ``i``'s time series: speed, action, Q-values, reward and finite TTC."""
    root, n, states = _span(record, i)
    decisions = np.arange(n)  # decision steps 0…L-1
    speed_kmh = record.state.ego.v[i, : n + 1].astype(np.float64) * 3.6
    send_scalars(rec, f"{root}/speed_kmh", states, speed_kmh)
    actions = record.action[i, :n]
    send_scalars(rec, f"{root}/action", decisions, actions)
    if record.q_values is not None:
        for a, name in enumerate(ACTIONS):
            rec.log(
                f"{root}/q/{name}",
                rr.SeriesLines(names=name, colors=ACTION_COLOURS[a]),
                static=True,
            )
            send_scalars(rec, f"{root}/q/{name}", decisions, record.q_values[i, :n, a])
    send_scalars(rec, f"{root}/reward", decisions + 1, record.reward[i, :n])
    ttc = record.ttc[i, :n]
    finite = np.isfinite(ttc)
    send_scalars(rec, f"{root}/ttc", (decisions + 1)[finite], ttc[finite])

    rec.log(f"{root}/action", rr.SeriesPoints(names="action", marker_sizes=2.0), static=True)
    rec.log(f"{root}/ttc", rr.SeriesPoints(names="TTC (s)", marker_sizes=2.0), static=True)
    rec.log(f"{root}/reward", rr.SeriesLines(names="reward"), static=True)
    rec.log(f"{root}/speed_kmh", rr.SeriesLines(names="speed (km/h)"), static=True)


def _log_events(rec: rr.RecordingStream, record: EpisodeRecord, i: int) -> None:
    """Episode ``i``'s text log: each action, then how the episode ended."""
    root, n, states = _span(record, i)
    actions = record.action[i, :n]
    end, level = {
        "collision": ("collision", "WARN"),
        "goal": ("goal reached", "INFO"),
        "truncated": (f"truncated after {n} steps", "INFO"),
    }[record.outcome(i)]
    struck = record.struck_while_stopped[i, :n]
    texts = [
        ACTIONS[a] + (" · struck while stopped" if hit else "")
        for a, hit in zip(actions, struck, strict=True)
    ]
    levels = ["WARN" if hit else "DEBUG" for hit in struck] + [level]
    texts.append(end)
    rec.send_columns(
        f"{root}/events",
        indexes=_steps(states),
        columns=rr.TextLog.columns(text=texts, level=levels),
    )


def episode_blueprint(
    num_episodes: int,
    has_q: bool,
    env: UrbanPedestrians,
    params: EnvParams,
    *,
    x_range: tuple[float, float] | None = None,
) -> rrb.Blueprint:
    """The saved layout: a tab per episode (world over ``x_range``, grids, curves, log)."""
    x_min, x_max, y_half = map_extent(env, params)
    if x_range is not None:
        x_min, x_max = x_range
        y_half = min(y_half, 0.25 * (x_max - x_min))
    bounds = rrb.VisualBounds2D(x_range=[x_min, x_max], y_range=[-y_half, y_half])
    tabs = []
    for i in range(num_episodes):
        root = f"/episode/{i}"
        world = rrb.Spatial2DView(
            name=f"episode {i}",
            origin="/",
            contents=["+ /map/**", f"+ {root}/world/**"],
            visual_bounds=bounds,
            background=MAP_COLOURS[OFF_ROAD],
        )
        grids = rrb.Horizontal(
            *[rrb.Spatial2DView(name=name, origin=f"{root}/grid/{name}") for name in GRID_CHANNELS]
        )
        curves = [
            rrb.TimeSeriesView(
                name="speed (km/h), reward, TTC (s)",
                origin=root,
                contents=[f"+ {root}/speed_kmh", f"+ {root}/reward", f"+ {root}/ttc"],
            ),
            rrb.TimeSeriesView(
                name="Q-values and action" if has_q else "action",
                origin=root,
                contents=[f"+ {root}/q/**", f"+ {root}/action"],
            ),
            rrb.TextLogView(name="actions", origin=f"{root}/events"),
        ]
        tabs.append(
            rrb.Vertical(
                world,
                rrb.Horizontal(grids, *curves, column_shares=[3, 2, 2, 2]),
                row_shares=[2, 1],
                name=f"episode {i}",
            )
        )
    return rrb.Blueprint(
        rrb.Tabs(*tabs),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=STEP_TIMELINE),
    )


def open_recording(
    path: str | Path, application_id: str, blueprint: rrb.Blueprint
) -> rr.RecordingStream:
    """A recording stream saving to ``path`` (parents created); OSError if it cannot be written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(application_id)
    try:
        rec.save(path, default_blueprint=blueprint)
    except RuntimeError as err:  # rerun reports file errors as RuntimeError
        raise OSError(f"cannot write {path}: {err}") from err
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush ``rec`` and close its file (disconnecting writes the footer)."""
    rec.flush()
    rec.disconnect()


def write_episodes(
    path: str | Path,
    record: EpisodeRecord,
    env: UrbanPedestrians,
    env_params: EnvParams | None = None,
    *,
    application_id: str = "drqn_jax",
    blueprint: rrb.Blueprint | None = None,
) -> None:
    """Log :func:`collect_episodes`' episodes to a new ``.rrd`` file (layout ``blueprint``)."""
    env_params = env.default_params if env_params is None else env_params
    if blueprint is None:
        has_q = record.q_values is not None
        blueprint = episode_blueprint(record.num_episodes, has_q, env, env_params)
    rec = open_recording(path, application_id, blueprint)
    try:
        log_map(rec, env, env_params)
        hud = hud_labels(record, env, env_params)
        for i in range(record.num_episodes):
            _log_episode(rec, record, i, env, env_params, hud[i])
    finally:
        close_recording(rec)


def record_episodes(
    path: str | Path,
    agent: Agent,
    key: jax.Array,
    num_episodes: int,
    env: UrbanPedestrians,
    env_params: EnvParams | None = None,
    *,
    network: Network | None = None,
    network_params: Any = None,
    application_id: str = "drqn_jax",
) -> None:
    """Record the episodes :func:`drqn_jax.evaluate` plays with ``key``; ``network`` adds Q."""
    record = collect_episodes(
        agent, key, num_episodes, env, env_params, network=network, network_params=network_params
    )
    write_episodes(path, record, env, env_params, application_id=application_id)
