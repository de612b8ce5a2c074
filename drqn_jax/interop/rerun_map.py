"""A rerun recording's static map (SPEC §1) and behaviour annotations; y is negated
(:func:`to_view`) so the ego drives on the right as in SPEC §1."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import rerun as rr

from drqn_jax.env.params import EnvParams
from drqn_jax.env.road_map import (
    CROSSING_AREA,
    ROAD,
    WALKWAY,
    crosswalk_centres,
    intersection_centres,
)
from drqn_jax.env.state import BEHAVIOURS
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.env.viewer import BEHAVIOUR_COLOURS, GOAL_COLOUR, LANE_MARK_COLOUR, MAP_COLOURS

__all__ = ["MapRegion", "log_map", "map_extent", "map_regions", "to_view"]

_VIEW_FLIP = np.array([1.0, -1.0], np.float32)


def to_view(xy: np.ndarray) -> np.ndarray:
    """Simulator (x, y) → logged (x, −y), (..., 2) float32 (rerun's 2D y axis points down)."""
    return (np.asarray(xy, np.float32) * _VIEW_FLIP).astype(np.float32)


@dataclasses.dataclass(frozen=True)
class MapRegion:
    """An axis-aligned rectangle (simulator frame, m) of one semantic class."""

    name: str
    semantic: int
    x_min: float
    x_max: float
    y_min: float
    y_max: float


def _f(x: Any) -> float:
    return float(np.asarray(x))


def map_extent(env: UrbanPedestrians, params: EnvParams) -> tuple[float, float, float]:
    """``(x_min, x_max, y_half)`` of the drawn map: everywhere an ego or pedestrian can be."""
    x_min = min(0.0, _f(params.ego_start_s) + env.static.grid_x_min)
    x_max = _f(params.goal_x) + max(_f(params.spawn_max), _f(params.despawn_ahead))
    y_half = max(-env.static.grid_y_min, _f(params.lane_width) + _f(params.sidewalk_width))
    return x_min, x_max, y_half


def map_regions(env: UrbanPedestrians, params: EnvParams) -> list[MapRegion]:
    """The SPEC §1 map as rectangles of the class ``semantic_class`` gives their interior."""
    x_min, x_max, y_half = map_extent(env, params)
    lane, side = _f(params.lane_width), _f(params.sidewalk_width)
    half_street, cw = 0.5 * _f(params.cross_street_width), _f(params.crosswalk_width)
    xcs = [float(x) for x in np.asarray(intersection_centres(params, env.static))]
    regions = [MapRegion("main road", ROAD, x_min, x_max, -lane, lane)]
    # main sidewalks, cut where they cross a cross street (there they are crosswalks)
    cuts = [x_min, *[c for xc in xcs for c in (xc - half_street, xc + half_street)], x_max]
    for lo, hi in zip(cuts[::2], cuts[1::2], strict=True):
        for sign in (1.0, -1.0):
            y0, y1 = sorted((sign * lane, sign * (lane + side)))
            regions.append(MapRegion("sidewalk", WALKWAY, lo, hi, y0, y1))
    for xc in xcs:
        for sign in (1.0, -1.0):  # sign: the ego's left (+) or right (-) side of the road
            y_far = sorted((sign * (lane + side), sign * y_half))
            y_near = sorted((sign * lane, sign * (lane + side)))
            x_street = (xc - half_street, xc + half_street)
            regions.append(MapRegion("cross street", ROAD, *x_street, *y_far))
            regions.append(MapRegion("crosswalk", CROSSING_AREA, *x_street, *y_near))
            for x_sign in (-1.0, 1.0):  # the cross street's sidewalks, before and after it
                x0, x1 = sorted((xc + x_sign * half_street, xc + x_sign * (half_street + side)))
                regions.append(MapRegion("cross-street sidewalk", WALKWAY, x0, x1, *y_far))
    for xw in np.asarray(crosswalk_centres(params, env.static)).tolist():
        regions.append(MapRegion("crosswalk", CROSSING_AREA, xw - cw / 2, xw + cw / 2, -lane, lane))
    return regions


def log_map(rec: rr.RecordingStream, env: UrbanPedestrians, params: EnvParams) -> None:
    """The static map (SPEC §1) under ``map/`` and the behaviour annotation context."""
    regions = map_regions(env, params)
    for entity, semantic in (("road", ROAD), ("walkways", WALKWAY), ("crosswalks", CROSSING_AREA)):
        rs = [r for r in regions if r.semantic == semantic]
        mins = to_view(np.array([[r.x_min, r.y_max] for r in rs]))  # y_max → view minimum
        sizes = np.array([[r.x_max - r.x_min, r.y_max - r.y_min] for r in rs], np.float32)
        rec.log(
            f"map/{entity}",
            rr.Boxes2D(
                mins=mins,
                sizes=sizes,
                colors=MAP_COLOURS[semantic],
                labels=[r.name for r in rs],
                show_labels=False,
                radii=0.08,
                draw_order=1.0,
            ),
            static=True,
        )
    x_min, x_max, _ = map_extent(env, params)
    lane = _f(params.lane_width)
    rec.log(
        "map/centre_line",
        rr.LineStrips2D(
            [to_view([[x_min, 0.0], [x_max, 0.0]])], colors=LANE_MARK_COLOUR, radii=0.1
        ),
        static=True,
    )
    goal = _f(params.goal_x)
    rec.log(
        "map/goal",
        rr.LineStrips2D(
            [to_view([[goal, -lane], [goal, lane]])], colors=GOAL_COLOUR, radii=0.25, labels="goal"
        ),
        static=True,
    )
    rec.log(
        "/",
        rr.AnnotationContext(
            [
                rr.AnnotationInfo(id=code, label=BEHAVIOURS[code], color=colour)
                for code, colour in BEHAVIOUR_COLOURS.items()
            ]
        ),
        static=True,
    )
