"""Rerun recordings of evaluated episodes (paper §V-E; SPEC §1–5, §8).

:func:`record_episodes` plays ``num_episodes`` greedy episodes of an agent
(:func:`~drqn_jax.interop.episode_record.collect_episodes`, the evaluated episodes
themselves) and logs them (:func:`write_episodes`) to one ``.rrd`` file (open it
with ``rerun FILE.rrd``; no viewer is needed to write it). Training curves are
:mod:`drqn_jax.interop.training_recording`'s, through the same stream helpers
(:func:`open_recording`, :func:`close_recording`).

Entity layout of an episode recording (timeline ``"step"`` = the env's
``state.time``; every episode has its own entity prefix ``episode/<i>``, so
episodes never overwrite each other and the saved blueprint shows one tab per
episode)::

    map/road, map/walkways, map/crosswalks   Boxes2D, static (SPEC §1 regions)
    map/centre_line, map/goal                 LineStrips2D, static
    episode/<i>/world/ego                     Boxes2D, steps 0…L, labelled with the HUD text
                                              (blue; magenta from a collision on)
    episode/<i>/world/pedestrians             Points2D (radius = ped_radius), steps 0…L
    episode/<i>/world/headings                Arrows2D: velocity × ttc_horizon, steps 0…L
    episode/<i>/grid/<channel>                Image (45, 30) float32, steps 0…L, one entity
                                              per channel: occupancy, heading, speed, semantics
    episode/<i>/speed_kmh                     Scalars, steps 0…L
    episode/<i>/action                        Scalars (action code), steps 0…L-1
    episode/<i>/q/<action name>               Scalars, steps 0…L-1 (DRQN only)
    episode/<i>/reward                        Scalars, steps 1…L
    episode/<i>/ttc                           Scalars, steps 1…L where TTC is finite
    episode/<i>/events                        TextLog: action names at 0…L-1 (a warning
                                              where a pedestrian struck the standing
                                              car), end at L

L is the episode's length. Step t shows the state the agent sees before its
t-th decision (t = 0 is the reset state, t = L the state the episode ended
in) with its observation grid and speed; ``action`` and ``q`` at t are the
decision taken in that state; ``reward`` and ``ttc`` at t are what the step
*into* state t produced (so the collision's −10 and TTC 0 sit on the frame
that shows the collision). TTC is logged only where it is finite (``inf``:
no overlap within the horizon or the ego stopped, SPEC §5), as points. Steps
after the episode ended are not logged.

World coordinates are the simulator's metres with **y negated** (rerun's 2D views
point y down), see :func:`drqn_jax.interop.rerun_map.to_view`; the static map is
:mod:`drqn_jax.interop.rerun_map`'s. Grid images are the observation as the network
sees it: row 0 is 5 m behind the ego, column 0 is 15 m to its right (SPEC §4).

Colours: the palette of :mod:`drqn_jax.env.viewer` (the Gymnasium frames use it
too); pedestrians are coloured by behaviour (crossing green, jaywalking red, sidewalk
orange; an ``AnnotationContext`` on ``/`` names the class ids) and faded while
occluded (``EnvParams.occlusion_prob``).

The ego's label at step t is the HUD of state t, the text the rendered frames
show (:func:`drqn_jax.env.viewer.hud_glyphs` read back by
:func:`~drqn_jax.env.viewer.hud_text`), e.g. ``step 12  36.0 km/h  accelerate
TTC 1.5 s``: the step, the speed, the action that led to the state (``-`` at
t = 0) and the TTC of state t itself (``-`` when infinite), computed for all
states by one jitted ``vmap`` (:func:`hud_labels`). The ``ttc`` scalars are the
step's ``info["ttc"]``, measured before far or finished pedestrians are
replaced, so the two can differ on a step that replaced one.
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
    "write_episodes",
]

STEP_TIMELINE = "step"
GRID_CHANNELS = ("occupancy", "heading", "speed", "semantics")  # SPEC §4 channel order


# --- logging episodes ------------------------------------------------------------


def _steps(values: np.ndarray | range) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(STEP_TIMELINE, sequence=np.asarray(values, np.int64))]


def _scalars(rec: rr.RecordingStream, entity: str, steps: np.ndarray, values: np.ndarray) -> None:
    if len(steps):
        rec.send_columns(
            entity,
            indexes=_steps(steps),
            columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)),
        )


@cached_program
def _hud_program(env: UrbanPedestrians) -> Any:
    """``(states, params) -> glyphs``: :func:`~drqn_jax.env.viewer.hud_glyphs` over
    states with leaves (N, T + 1, ...), one jitted double ``vmap``; built once per env."""
    one = partial(hud_glyphs, static=env.static)
    return jax.jit(jax.vmap(jax.vmap(one, in_axes=(0, None)), in_axes=(0, None)))


def hud_labels(record: EpisodeRecord, env: UrbanPedestrians, params: EnvParams) -> np.ndarray:
    """The HUD of every recorded state (SPEC §5 TTC of the state itself), as
    :func:`~drqn_jax.env.viewer.hud_glyphs`: (N, T + 1, 2, L) int32, one jitted call;
    :func:`~drqn_jax.env.viewer.hud_text` turns one (2, L) entry into the ego's label."""
    return np.asarray(_hud_program(env)(record.state, params))


def _log_episode(
    rec: rr.RecordingStream,
    record: EpisodeRecord,
    i: int,
    env: UrbanPedestrians,
    params: EnvParams,
    hud: np.ndarray,
) -> None:
    """Log episode ``i`` of ``record`` under ``episode/<i>`` (layout: module docstring);
    ``hud``: its states' HUD glyphs, (T + 1, 2, L) (:func:`hud_labels`)."""
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
    """The top view of episode ``i``: the ego (red from its first collision on, its
    HUD label), the pedestrians (coloured by behaviour, faded where occluded, of radius
    ``ped_radius`` m) and their headings (``heading_s`` seconds of walking), at state
    steps 0…L."""
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
    # pedestrians the grid leaves out this step (EnvParams.occlusion_prob) are faded
    alpha = np.where(peds.visible.reshape(-1), 255, OCCLUDED_ALPHA).astype(np.uint8)
    colours = np.concatenate([palette[behaviour], alpha[:, None]], axis=1)
    positions = to_view(peds.position.reshape(-1, 2))
    lengths = [num_peds] * (n + 1)
    # the behaviour names (annotation context) show on hover, not over every pedestrian
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
    """Episode ``i``'s observation grid (rows, cols, channels) as one greyscale image
    per channel, at state steps 0…L."""
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
    """Episode ``i``'s time series: speed (km/h, state steps), action, Q-values (when
    recorded), reward and TTC (finite only), at decision steps."""
    root, n, states = _span(record, i)
    decisions = np.arange(n)  # decision steps 0…L-1
    speed_kmh = record.state.ego.v[i, : n + 1].astype(np.float64) * 3.6
    _scalars(rec, f"{root}/speed_kmh", states, speed_kmh)
    actions = record.action[i, :n]
    _scalars(rec, f"{root}/action", decisions, actions)
    if record.q_values is not None:
        for a, name in enumerate(ACTIONS):
            rec.log(
                f"{root}/q/{name}",
                rr.SeriesLines(names=name, colors=ACTION_COLOURS[a]),
                static=True,
            )
            _scalars(rec, f"{root}/q/{name}", decisions, record.q_values[i, :n, a])
    _scalars(rec, f"{root}/reward", decisions + 1, record.reward[i, :n])
    ttc = record.ttc[i, :n]
    finite = np.isfinite(ttc)
    _scalars(rec, f"{root}/ttc", (decisions + 1)[finite], ttc[finite])

    rec.log(f"{root}/action", rr.SeriesPoints(names="action", marker_sizes=2.0), static=True)
    rec.log(f"{root}/ttc", rr.SeriesPoints(names="TTC (s)", marker_sizes=2.0), static=True)
    rec.log(f"{root}/reward", rr.SeriesLines(names="reward"), static=True)
    rec.log(f"{root}/speed_kmh", rr.SeriesLines(names="speed (km/h)"), static=True)


def _log_events(rec: rr.RecordingStream, record: EpisodeRecord, i: int) -> None:
    """Episode ``i``'s text log: each decision's action (a warning where a pedestrian
    struck the standing car), then how the episode ended."""
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
    """The layout :func:`write_episodes` saves: one tab per episode.

    Each tab shows the world over the map (x from ``x_range``, default the whole
    drawn map), the four grid channels, speed/reward/TTC, Q-values and action,
    and the action log. Pass another one to :func:`write_episodes` to zoom, e.g.
    ``episode_blueprint(1, False, env, params, x_range=(80, 140))``.
    """
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
    """Flush ``rec`` and close its file (rerun writes the footer on disconnect)."""
    rec.flush()
    rec.disconnect()  # writes the footer and closes the file


def write_episodes(
    path: str | Path,
    record: EpisodeRecord,
    env: UrbanPedestrians,
    env_params: EnvParams | None = None,
    *,
    application_id: str = "drqn_jax",
    blueprint: rrb.Blueprint | None = None,
) -> None:
    """Log :func:`collect_episodes`' episodes to a new ``.rrd`` file (layout: module docstring).

    The file also holds ``blueprint`` as the default layout (default:
    :func:`episode_blueprint`, one tab per episode).
    """
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
    """Play ``num_episodes`` episodes of ``agent`` and save them as a rerun recording.

    Episode i is the one :func:`drqn_jax.evaluate` plays with the same
    ``key`` (``fold_in(key, i)``). Pass the DRQN's ``network`` and
    ``network_params`` to record its four Q-values per step (what
    ``drqn_agent(network, network_params)`` takes the argmax of). The entity
    layout, timeline and conventions are in the module docstring.
    """
    record = collect_episodes(
        agent,
        key,
        num_episodes,
        env,
        env_params,
        network=network,
        network_params=network_params,
    )
    write_episodes(path, record, env, env_params, application_id=application_id)


# --- training curves --------------------------------------------------------------
