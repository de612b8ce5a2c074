"""Rerun recordings (SPEC §8): a static ``map/``; per episode ``episode/<i>/`` ``world/``,
``grid/<channel>`` images, scalars and ``events`` on timeline ``"step"`` (step t: the state
before decision t; ``reward``/``ttc`` at t from the step into it). Training curves on
``"episode"`` (a run) or ``"env_steps"`` (a study)."""

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any

import jax
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from drqn_jax.env.params import EnvParams
from drqn_jax.env.road_map import (
    CROSSING_AREA,
    OFF_ROAD,
    ROAD,
    WALKWAY,
    crosswalk_centres,
    intersection_centres,
)
from drqn_jax.env.state import ACTIONS, BEHAVIOURS
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.env.viewer import (
    ACTION_COLOURS,
    BEHAVIOUR_COLOURS,
    EGO_COLLISION_COLOUR,
    EGO_COLOUR,
    GOAL_COLOUR,
    LANE_MARK_COLOUR,
    MAP_COLOURS,
    OCCLUDED_ALPHA,
    hud_glyphs,
    hud_text,
)
from drqn_jax.interop.episode_record import EpisodeRecord
from drqn_jax.programs import cached_program

STEP_TIMELINE = "step"
GRID_CHANNELS = ("occupancy", "heading", "speed", "semantics")  # SPEC §4 channel order
_VIEW_FLIP = np.array([1.0, -1.0], np.float32)


def to_view(xy: np.ndarray) -> np.ndarray:
    """Simulator (x, y) → logged (x, −y), (..., 2) float32 (rerun's 2D y axis points down)."""
    return np.asarray(xy, np.float32) * _VIEW_FLIP


def map_extent(env: UrbanPedestrians, params: EnvParams) -> tuple[float, float, float]:
    """``(x_min, x_max, y_half)`` of the drawn map: everywhere an ego or pedestrian can be."""
    x_min = min(0.0, float(params.ego_start_s) + env.static.grid_x_min)
    x_max = float(params.goal_x) + max(float(params.spawn_max), float(params.despawn_ahead))
    y_half = max(-env.static.grid_y_min, float(params.lane_width) + float(params.sidewalk_width))
    return x_min, x_max, y_half


def _map_regions(env: UrbanPedestrians, params: EnvParams) -> dict[int, list[tuple]]:
    """The SPEC §1 map as ``(name, x_min, x_max, y_min, y_max)`` rectangles (m), keyed by
    the class ``semantic_class`` gives their interior."""
    x_min, x_max, y_half = map_extent(env, params)
    lane, side = float(params.lane_width), float(params.sidewalk_width)
    half_street, cw = 0.5 * float(params.cross_street_width), float(params.crosswalk_width)
    xcs = [float(x) for x in np.asarray(intersection_centres(params, env.static))]
    road, walkways, crosswalks = [("main road", x_min, x_max, -lane, lane)], [], []
    # main sidewalks, cut where they cross a cross street (there they are crosswalks)
    cuts = [x_min, *[c for xc in xcs for c in (xc - half_street, xc + half_street)], x_max]
    for lo, hi in zip(cuts[::2], cuts[1::2], strict=True):
        for sign in (1.0, -1.0):
            walkways.append(("sidewalk", lo, hi, *sorted((sign * lane, sign * (lane + side)))))
    for xc in xcs:
        for sign in (1.0, -1.0):  # sign: the ego's left (+) or right (-) side of the road
            y_far = sorted((sign * (lane + side), sign * y_half))
            y_near = sorted((sign * lane, sign * (lane + side)))
            x_street = (xc - half_street, xc + half_street)
            road.append(("cross street", *x_street, *y_far))
            crosswalks.append(("crosswalk", *x_street, *y_near))
            for x_sign in (-1.0, 1.0):  # the cross street's sidewalks, before and after it
                x0, x1 = sorted((xc + x_sign * half_street, xc + x_sign * (half_street + side)))
                walkways.append(("cross-street sidewalk", x0, x1, *y_far))
    for xw in np.asarray(crosswalk_centres(params, env.static)).tolist():
        crosswalks.append(("crosswalk", xw - cw / 2, xw + cw / 2, -lane, lane))
    return {ROAD: road, WALKWAY: walkways, CROSSING_AREA: crosswalks}


def log_map(rec: rr.RecordingStream, env: UrbanPedestrians, params: EnvParams) -> None:
    """The static map (SPEC §1) under ``map/`` and the behaviour annotation context."""
    regions = _map_regions(env, params)
    for entity, semantic in (("road", ROAD), ("walkways", WALKWAY), ("crosswalks", CROSSING_AREA)):
        box = np.array([r[1:] for r in regions[semantic]])  # (R, 4) x_min, x_max, y_min, y_max
        rec.log(
            f"map/{entity}",
            rr.Boxes2D(
                mins=to_view(box[:, [0, 3]]),  # y_max → view minimum
                sizes=(box[:, [1, 3]] - box[:, [0, 2]]).astype(np.float32),
                colors=MAP_COLOURS[semantic],
                labels=[r[0] for r in regions[semantic]],
                show_labels=False,
                radii=0.08,
                draw_order=1.0,
            ),
            static=True,
        )
    x_min, x_max, _ = map_extent(env, params)
    lane, goal = float(params.lane_width), float(params.goal_x)
    lines = {  # entity: (end points, colour, radius, label)
        "centre_line": ([[x_min, 0.0], [x_max, 0.0]], LANE_MARK_COLOUR, 0.1, None),
        "goal": ([[goal, -lane], [goal, lane]], GOAL_COLOUR, 0.25, "goal"),
    }
    for entity, (ends, colour, radius, label) in lines.items():
        strip = rr.LineStrips2D([to_view(ends)], colors=colour, radii=radius, labels=label)
        rec.log(f"map/{entity}", strip, static=True)
    behaviours = BEHAVIOUR_COLOURS.items()
    labels = [rr.AnnotationInfo(id=b, label=BEHAVIOURS[b], color=c) for b, c in behaviours]
    rec.log("/", rr.AnnotationContext(labels), static=True)


def _steps(values: np.ndarray | range, timeline: str = STEP_TIMELINE) -> list[rr.TimeColumn]:
    return [rr.TimeColumn(timeline, sequence=np.asarray(values, np.int64))]


def send_scalars(
    rec: rr.RecordingStream,
    entity: str,
    steps: np.ndarray,
    values: np.ndarray,
    style: Any,
    timeline: str = STEP_TIMELINE,
) -> None:
    """``values`` (E,) at the sequence ``steps`` (E,) of ``timeline``, as float64 scalars;
    ``style`` (e.g. ``rr.SeriesLines``) is logged static beside them."""
    rec.log(entity, style, static=True)
    if len(steps):
        rec.send_columns(
            entity,
            indexes=_steps(steps, timeline),
            columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)),
        )


@cached_program
def _hud_program(env: UrbanPedestrians) -> Any:
    """``(states, params) -> (N, T + 1, 2, L) int32``: :func:`hud_glyphs` of every recorded
    state (leaves (N, T + 1, ...)), one jitted call."""
    one = partial(hud_glyphs, static=env.static)
    return jax.jit(jax.vmap(jax.vmap(one, in_axes=(0, None)), in_axes=(0, None)))


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
    lengths = [peds.position.shape[1]] * (n + 1)  # P points per step
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


def _log_grid(rec: rr.RecordingStream, record: EpisodeRecord, i: int) -> None:
    """Episode ``i``'s observation grid, one greyscale image per channel."""
    root, n, states = _span(record, i)
    rows, cols = record.grid.shape[2:4]
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
    ttc = record.ttc[i, :n]
    finite = np.isfinite(ttc)
    speed_kmh = record.state.ego.v[i, : n + 1].astype(np.float64) * 3.6
    points = partial(rr.SeriesPoints, marker_sizes=2.0)
    series = {
        "speed_kmh": (rr.SeriesLines(names="speed (km/h)"), states, speed_kmh),
        "action": (points(names="action"), decisions, record.action[i, :n]),
        "reward": (rr.SeriesLines(names="reward"), decisions + 1, record.reward[i, :n]),
        "ttc": (points(names="TTC (s)"), (decisions + 1)[finite], ttc[finite]),
    }
    if record.q_values is not None:
        for a, name in enumerate(ACTIONS):
            style = rr.SeriesLines(names=name, colors=ACTION_COLOURS[a])
            series[f"q/{name}"] = (style, decisions, record.q_values[i, :n, a])
    for entity, (style, at, values) in series.items():
        send_scalars(rec, f"{root}/{entity}", at, values, style)


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
    return collapsed_blueprint(rrb.Tabs(*tabs), STEP_TIMELINE)


def collapsed_blueprint(layout: Any, timeline: str) -> rrb.Blueprint:
    """``layout`` with the blueprint, selection and time (on ``timeline``) panels collapsed."""
    return rrb.Blueprint(
        layout,
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=timeline),
    )


@contextmanager
def recording_file(path: str | Path, blueprint: rrb.Blueprint) -> Iterator[rr.RecordingStream]:
    """A recording stream saving to ``path`` (parents created), flushed and closed (the
    footer written) on exit; OSError if the file cannot be written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("drqn_jax")
    try:
        rec.save(path, default_blueprint=blueprint)
    except RuntimeError as err:  # rerun reports file errors as RuntimeError
        raise OSError(f"cannot write {path}: {err}") from err
    try:
        yield rec
    finally:
        rec.flush()
        rec.disconnect()


def write_episodes(
    path: str | Path,
    record: EpisodeRecord,
    env: UrbanPedestrians,
    env_params: EnvParams | None = None,
    *,
    blueprint: rrb.Blueprint | None = None,
) -> None:
    """Log :func:`collect_episodes`' episodes to a new ``.rrd`` file (layout ``blueprint``)."""
    params = env.default_params if env_params is None else env_params
    if blueprint is None:
        blueprint = episode_blueprint(record.num_episodes, record.q_values is not None, env, params)
    with recording_file(path, blueprint) as rec:
        log_map(rec, env, params)
        hud = np.asarray(_hud_program(env)(record.state, params))
        for i in range(record.num_episodes):
            _log_world(rec, record, i, hud[i], float(params.ped_radius), env.static.ttc_horizon)
            _log_grid(rec, record, i)
            _log_series(rec, record, i)
            _log_events(rec, record, i)


_REQUIRED_METRICS = ("episode", "episode_return", "length", "collision", "mean_loss", "epsilon")
EPISODE_TIMELINE = "episode"
ENV_STEPS_TIMELINE = "env_steps"  # a study's curves
COLLISION_RATE_WINDOW = 20  # episodes in the running collision/goal rates (as the progress bar)


def running_mean(values: np.ndarray, window: int = COLLISION_RATE_WINDOW) -> np.ndarray:
    """(N,) float64 mean of ``values[max(0, k - window + 1) : k + 1]`` for each k."""
    values = np.asarray(values, np.float64)
    total = np.concatenate([[0.0], np.cumsum(values)])
    k = np.arange(len(values))
    start = np.maximum(0, k - window + 1)
    return (total[k + 1] - total[start]) / (k + 1 - start)


def record_training(path: str | Path, metrics: Mapping[str, np.ndarray]) -> None:
    """Save training curves to ``path``: ``metrics`` (N,) arrays per recorded episode, as
    ``recorded_metrics`` returns them; rates are running means."""
    missing = [name for name in _REQUIRED_METRICS if name not in metrics]
    if missing:
        raise ValueError(f"record_training: metrics lack {', '.join(missing)}")
    m = {name: np.asarray(v) for name, v in metrics.items()}
    curves = {
        "return": m["episode_return"],
        "length": m["length"],
        "loss": m["mean_loss"],
        "epsilon": m["epsilon"],
        "collision_rate": running_mean(m["collision"]),
    }
    if "goal" in m:
        curves["goal_rate"] = running_mean(m["goal"])
    if "distance" in m:
        curves["distance"] = m["distance"]
    if "mean_speed" in m:
        curves["mean_speed_kmh"] = m["mean_speed"].astype(np.float64) * 3.6
    blueprint = _series_blueprint({name: f"/training/{name}" for name in curves})
    with recording_file(path, blueprint) as rec:
        for name, values in curves.items():
            style = rr.SeriesLines(names=name)
            send_scalars(rec, f"training/{name}", m["episode"], values, style, EPISODE_TIMELINE)


def _series_blueprint(views: Mapping[str, str], timeline: str = EPISODE_TIMELINE) -> rrb.Blueprint:
    """One time-series view per ``name → origin entity``, on ``timeline``."""
    series = [rrb.TimeSeriesView(name=name, origin=o) for name, o in views.items()]
    return collapsed_blueprint(rrb.Grid(*series), timeline)


def record_study_curves(path: str | Path, curves: Mapping[str, Mapping[str, Any]]) -> None:
    """Save ``load_curves`` per config as ``curves/<metric>/<config>/{mean,low,high,seed<k>}``."""
    metrics = sorted({m for by_metric in curves.values() for m in by_metric})
    views = {m: f"/curves/{m}" for m in metrics}
    with recording_file(path, _series_blueprint(views, ENV_STEPS_TIMELINE)) as rec:
        for name, by_metric in curves.items():
            for metric, c in by_metric.items():
                series = {part: (c.env_steps, getattr(c, part)) for part in ("mean", "low", "high")}
                series |= {
                    f"seed{k}": xy for k, xy in enumerate(zip(c.seed_steps, c.seeds, strict=True))
                }
                for part, (at, values) in series.items():
                    entity = f"curves/{metric}/{name}/{part}"
                    style = rr.SeriesLines(names=f"{name} {part}")
                    send_scalars(rec, entity, at, values, style, ENV_STEPS_TIMELINE)
