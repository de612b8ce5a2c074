"""How the env is drawn (SPEC §1–5): palette, raster (:func:`render_frame`, pure JAX) and
HUD (step, km/h, last action, TTC as :data:`GLYPHS` indices) shared with rerun recordings."""

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.env.collision import classify_hits, time_to_collision
from drqn_jax.env.params import EnvParams, StaticEnvParams
from drqn_jax.env.road_map import (
    CROSSING_AREA,
    OFF_ROAD,
    ROAD,
    WALKWAY,
    lane_centre_y,
    semantic_class,
)
from drqn_jax.env.state import ACTIONS, CROSSING, JAYWALKING, NUM_ACTIONS, SIDEWALK, EnvState

RGB = tuple[int, int, int]

#: RGB by semantic class (SPEC §1).
MAP_COLOURS: dict[int, RGB] = {
    OFF_ROAD: (58, 66, 56),
    WALKWAY: (168, 168, 158),
    CROSSING_AREA: (232, 232, 222),  # the raster's light zebra stripes; the dark ones are road
    ROAD: (78, 78, 84),
}
LANE_MARK_COLOUR: RGB = (220, 220, 200)
GOAL_COLOUR: RGB = (250, 200, 40)
EGO_COLOUR: RGB = (40, 110, 235)
EGO_COLLISION_COLOUR: RGB = (230, 40, 210)  # magenta: a red jaywalker on it still shows
#: RGB by pedestrian behaviour (SPEC §3).
BEHAVIOUR_COLOURS: dict[int, RGB] = {
    CROSSING: (40, 190, 80),
    JAYWALKING: (235, 60, 50),
    SIDEWALK: (250, 165, 30),
}
#: RGB by action (paper §IV-B).
ACTION_COLOURS: tuple[RGB, ...] = ((40, 190, 80), (250, 165, 30), (235, 60, 50), (80, 150, 255))
OCCLUDED_ALPHA = 70  # alpha (of 255) of a pedestrian the grid leaves out this step
PED_OUTLINE_COLOUR: RGB = (15, 15, 20)
HUD_TEXT_COLOUR: RGB = (240, 240, 240)
HUD_BAND_COLOUR: RGB = (10, 10, 14)
HUD_BAND_ALPHA = 0.7  # the world stays faintly visible behind the HUD

# The raster's view: 240 × 480 pixels.
RENDER_BEHIND_M = 10.0
RENDER_AHEAD_M = 50.0
RENDER_HALF_WIDTH_M = 15.0
RENDER_PIXELS_PER_M = 8
#: Smallest drawn pedestrian radius (pixels; 0.3 m is 2.4 px), plus a 1-pixel outline.
MIN_PED_RADIUS_PX = 5
_PED_OUTLINE_PX = 1

GLYPHS = " 0123456789.-/_TCabcdehklmnoprstw"
# 5 × 7 bitmaps of GLYPHS, eleven side by side in each block of seven rows.
_FONT_ROWS = (
    # " 0123456789"
    "..... .###. ..#.. .###. ##### ...#. ##### ..##. ##### .###. .###.",
    "..... #...# .##.. #...# ...#. ..##. #.... .#... ....# #...# #...#",
    "..... #..## ..#.. ....# ..#.. .#.#. ####. #.... ...#. #...# #...#",
    "..... #.#.# ..#.. ...#. ...#. #..#. ....# ####. ..#.. .###. .####",
    "..... ##..# ..#.. ..#.. ....# ##### ....# #...# .#... #...# ....#",
    "..... #...# ..#.. .#... #...# ...#. #...# #...# .#... #...# ...#.",
    "..... .###. .###. ##### .###. ...#. .###. .###. .#... .###. .##..",
    # ".-/_TCabcde"
    "..... ..... ..... ..... ##### .###. ..... #.... ..... ....# .....",
    "..... ..... ....# ..... ..#.. #...# ..... #.... ..... ....# .....",
    "..... ..... ...#. ..... ..#.. #.... .###. #.##. .###. .##.# .###.",
    "..... .###. ..#.. ..... ..#.. #.... ....# ##..# #.... #..## #...#",
    "..... ..... .#... ..... ..#.. #.... .#### #...# #.... #...# #####",
    ".##.. ..... #.... ..... ..#.. #...# #...# #...# #...# #...# #....",
    ".##.. ..... ..... ##### ..#.. .###. .#### ####. .###. .#### .###.",
    # "hklmnoprstw"
    "#.... #.... .##.. ..... ..... ..... ..... ..... ..... .#... .....",
    "#.... #.... ..#.. ..... ..... ..... ..... ..... ..... .#... .....",
    "#.##. #..#. ..#.. ##.#. #.##. .###. ####. #.##. .###. ###.. #...#",
    "##..# #.#.. ..#.. #.#.# ##..# #...# #...# ##..# #.... .#... #...#",
    "#...# ##... ..#.. #.#.# #...# #...# ####. #.... .###. .#... #.#.#",
    "#...# #.#.. ..#.. #...# #...# #...# #.... #.... ....# .#..# #.#.#",
    "#...# #..#. .###. #...# #...# .###. #.... #.... ####. ..##. .#.#.",
)
_INK = np.array([[[c == "#" for c in g] for g in row.split()] for row in _FONT_ROWS], bool)
#: (len(GLYPHS), 7, 5) bool bitmaps of GLYPHS.
FONT = _INK.reshape(3, 7, 11, 5).transpose(0, 2, 1, 3).reshape(len(GLYPHS), 7, 5)
FONT.setflags(write=False)
HUD_SCALE = 2  # pixels per font pixel
HUD_LINES = 2
_GLYPH_ROWS, _GLYPH_COLS = FONT.shape[1:]
_CELL_COLS = _GLYPH_COLS + 1  # one blank column between characters
_HUD_MARGIN_PX = 4
_GAP = -1  # an absent character: dropped from its line
_SPACE, _DIGIT0, _DOT = (GLYPHS.index(c) for c in " 0.")


def _codes(text: str, width: int = 0) -> np.ndarray:
    """(max(len(text), width),) int32 glyph indices of a static string, gap-padded."""
    return np.array([GLYPHS.index(c) for c in text] + [_GAP] * (width - len(text)), np.int32)


_ACTION_WIDTH = max(len(a) for a in ACTIONS)
# Row a + 1: action a's name; row 0: "-" (no action yet, last_action = -1).
_ACTION_CODES = np.array([_codes(name, _ACTION_WIDTH) for name in ("-", *ACTIONS)])
_STEP_DIGITS, _SPEED_DIGITS, _TTC_DIGITS = 5, 3, 3  # integer digits (larger values clip)
_TTC_WIDTH = _TTC_DIGITS + 4  # "ddd.d s"
#: Glyphs per HUD line: the longer line with its fields at their widest.
HUD_LINE_LENGTH = max(
    len("step ") + _STEP_DIGITS + len("  ") + _SPEED_DIGITS + 2 + len(" km/h"),
    _ACTION_WIDTH + len("  TTC ") + _TTC_WIDTH,
)


def _digits(n: jax.Array, width: int) -> jax.Array:
    """(width,) int32 digit glyphs of ``n`` (clipped), leading zeros as gaps."""
    n = jnp.clip(jnp.asarray(n, jnp.int32), 0, 10**width - 1)
    powers = jnp.asarray(10 ** np.arange(width - 1, -1, -1), jnp.int32)  # (width,)
    leading = (n < powers) & (powers > 1)
    return jnp.where(leading, _GAP, _DIGIT0 + (n // powers) % 10).astype(jnp.int32)


def _one_decimal(x: jax.Array, width: int) -> jax.Array:
    """(width + 2,) int32 glyphs of ``x`` >= 0 to one decimal."""
    x = jnp.where(jnp.isfinite(x), x, 0.0)
    tenths = jnp.clip(jnp.round(x * 10.0), 0, 10 ** (width + 1) - 1).astype(jnp.int32)
    point = jnp.full((1,), _DOT, jnp.int32)
    return jnp.concatenate([_digits(tenths // 10, width), point, _DIGIT0 + tenths[None] % 10])


def _line(pieces: list) -> tuple[jax.Array, jax.Array]:
    """One HUD line's (HUD_LINE_LENGTH,) int32 glyphs and colours from literal text and
    (glyphs, colour index) pieces: gaps dropped, left-aligned, space-padded."""
    pieces = [(_codes(p), 0) if isinstance(p, str) else p for p in pieces]
    codes = jnp.concatenate([jnp.asarray(c, jnp.int32) for c, _ in pieces])
    colours = jnp.concatenate([jnp.full(len(c), k, jnp.int32) for c, k in pieces])
    keep = codes != _GAP
    at = jnp.where(keep, jnp.cumsum(keep) - 1, HUD_LINE_LENGTH)  # gaps go out of range
    glyphs = jnp.full(HUD_LINE_LENGTH, _SPACE, jnp.int32).at[at].set(codes, mode="drop")
    return glyphs, jnp.zeros(HUD_LINE_LENGTH, jnp.int32).at[at].set(colours, mode="drop")


def _hud_layout(
    state: EnvState, params: EnvParams, static: StaticEnvParams
) -> tuple[jax.Array, jax.Array]:
    """(HUD_LINES, HUD_LINE_LENGTH) int32 glyphs and colours (0: text, a + 1: action a)."""
    ttc = time_to_collision(state.ego, state.pedestrians, params, static)  # SPEC §5
    no_ttc = _codes("-", _TTC_WIDTH)
    with_unit = jnp.concatenate([_one_decimal(ttc, _TTC_DIGITS), _codes(" s")])
    action = jnp.clip(state.last_action + 1, 0, NUM_ACTIONS)  # 0: none yet
    step = (_digits(state.time, _STEP_DIGITS), 0)
    speed = (_one_decimal(state.ego.v * 3.6, _SPEED_DIGITS), 0)
    name = (jnp.asarray(_ACTION_CODES)[action], action)
    ttc_text = (jnp.where(jnp.isfinite(ttc), with_unit, no_ttc), 0)
    lines = [_line(["step ", step, "  ", speed, " km/h"]), _line([name, "  TTC ", ttc_text])]
    return jnp.stack([g for g, _ in lines]), jnp.stack([c for _, c in lines])


def hud_glyphs(state: EnvState, params: EnvParams, static: StaticEnvParams) -> jax.Array:
    """(2, 23) int32 glyphs: ``step <t>  <speed> km/h`` / ``<last action>  TTC <ttc> s``."""
    return _hud_layout(state, params, static)[0]


def hud_text(glyphs: np.ndarray | jax.Array) -> str:
    """One :func:`hud_glyphs` result as a string, lines stripped and joined by two spaces."""
    lines = np.asarray(glyphs).reshape(-1, np.shape(glyphs)[-1])
    return "  ".join("".join(GLYPHS[i] for i in line).rstrip() for line in lines)


def _uint8(colour: RGB | list) -> jax.Array:
    return jnp.asarray(colour, jnp.uint8)


def _blend(under: jax.Array, colour: jax.Array, alpha: float) -> jax.Array:
    """``alpha`` of ``colour`` over ``under`` (uint8 (..., 3), broadcastable), uint8."""
    mixed = under.astype(jnp.float32) * (1.0 - alpha) + colour.astype(jnp.float32) * alpha
    return jnp.round(mixed).astype(jnp.uint8)


def _draw_map(xy: jax.Array, params: EnvParams, static: StaticEnvParams, pixel: float) -> jax.Array:
    """(H, W, 3) uint8 map (SPEC §1) at pixel centres ``xy`` (H, W, 2)."""
    cls = semantic_class(xy, params, static)
    palette = _uint8([MAP_COLOURS[c] for c in range(len(MAP_COLOURS))])
    image = palette[cls]
    # Zebra stripes, 0.5 m, parallel to the traffic they cross.
    along = jnp.where(jnp.abs(xy[..., 1]) < params.lane_width, xy[..., 1], xy[..., 0])
    dark_stripe = (cls == CROSSING_AREA) & (jnp.floor(along * 2.0) % 2 == 1)
    image = jnp.where(dark_stripe[..., None], palette[ROAD], image)
    # Dashed centre line, not across intersections (where the kerb side is no walkway).
    x = xy[0, :, 0]
    kerb = jnp.stack([x, jnp.full_like(x, params.lane_width + 0.5 * params.sidewalk_width)], -1)
    between_streets = semantic_class(kerb, params, static) == WALKWAY  # (W,)
    centre_line = (
        (cls == ROAD)
        & between_streets[None, :]
        & (jnp.abs(xy[..., 1]) < 0.1 + 0.5 * pixel)
        & (jnp.floor(xy[..., 0] / 3.0) % 2 == 0)
    )
    image = jnp.where(centre_line[..., None], _uint8(LANE_MARK_COLOUR), image)
    goal = (jnp.abs(xy[..., 0] - params.goal_x) < 0.25) & (jnp.abs(xy[..., 1]) < params.lane_width)
    return jnp.where(goal[..., None], _uint8(GOAL_COLOUR), image)


def _draw_ego(image: jax.Array, xy: jax.Array, state: EnvState, params: EnvParams) -> jax.Array:
    """The ego's box over ``image``, EGO_COLLISION_COLOUR in a collision (SPEC §5)."""
    inside = (jnp.abs(xy[..., 0] - state.ego.s) <= 0.5 * params.ego_length) & (
        jnp.abs(xy[..., 1] - lane_centre_y(params)) <= 0.5 * params.ego_width
    )
    collided, _ = classify_hits(state.ego, state.pedestrians, params)
    colour = jnp.where(collided, _uint8(EGO_COLLISION_COLOUR), _uint8(EGO_COLOUR))
    return jnp.where(inside[..., None], colour, image)


def _draw_pedestrians(
    image: jax.Array, xy: jax.Array, state: EnvState, params: EnvParams, pixel: float
) -> jax.Array:
    """Outlined pedestrian discs by behaviour, faded where occluded, lowest index on top."""
    peds = state.pedestrians
    radius = jnp.maximum(params.ped_radius, MIN_PED_RADIUS_PX * pixel)
    outer = radius + _PED_OUTLINE_PX * pixel
    d2 = jnp.sum((xy[:, :, None, :] - peds.position[None, None, :, :]) ** 2, axis=-1)  # (H,W,P)
    covered = d2 <= outer * outer
    first = jnp.argmax(covered, axis=-1)  # (H, W)
    d2_first = jnp.take_along_axis(d2, first[..., None], axis=-1)[..., 0]
    behaviour = jnp.clip(peds.behaviour[first], 0, len(BEHAVIOUR_COLOURS) - 1)
    colour = _uint8([BEHAVIOUR_COLOURS[b] for b in range(len(BEHAVIOUR_COLOURS))])[behaviour]
    fill = jnp.where(
        peds.visible[first][..., None], colour, _blend(image, colour, OCCLUDED_ALPHA / 255)
    )
    drawn = jnp.where((d2_first <= radius * radius)[..., None], fill, _uint8(PED_OUTLINE_COLOUR))
    return jnp.where(jnp.any(covered, axis=-1)[..., None], drawn, image)


def _draw_hud(image: jax.Array, glyphs: jax.Array, colours: jax.Array) -> jax.Array:
    """The HUD lines at the top left of ``image`` (H, W, 3) in a translucent band: each
    line a margin then its glyph rows, each character its glyph and a blank column."""
    height, width, _ = image.shape
    lines, length = glyphs.shape
    s, m = HUD_SCALE, _HUD_MARGIN_PX
    line_rows = m + _GLYPH_ROWS * s
    row, col = jnp.arange(height)[:, None], jnp.arange(width)[None, :] - m  # (H, 1), (1, W)
    line, gy = row // line_rows, (row % line_rows - m) // s
    char, gx = col // (_CELL_COLS * s), (col // s) % _CELL_COLS
    inside = (line < lines) & (gy >= 0) & (col >= 0) & (char < length) & (gx < _GLYPH_COLS)
    at = (jnp.minimum(line, lines - 1), jnp.clip(char, 0, length - 1))  # (H, W) each
    bitmap = jnp.asarray(FONT)[glyphs[at], jnp.maximum(gy, 0), jnp.minimum(gx, _GLYPH_COLS - 1)]
    used = jnp.max(jnp.where(glyphs != _SPACE, jnp.arange(length) + 1, 0))  # widest line
    band = (row < lines * line_rows + m) & (col < m + used * _CELL_COLS * s - s)
    image = jnp.where(
        band[..., None], _blend(image, _uint8(HUD_BAND_COLOUR), HUD_BAND_ALPHA), image
    )
    palette = _uint8([HUD_TEXT_COLOUR, *ACTION_COLOURS])
    return jnp.where((inside & bitmap)[..., None], palette[colours[at]], image)


def render_frame(
    state: EnvState,
    params: EnvParams,
    static: StaticEnvParams,
    *,
    behind_m: float = RENDER_BEHIND_M,
    ahead_m: float = RENDER_AHEAD_M,
    half_width_m: float = RENDER_HALF_WIDTH_M,
    pixels_per_m: int = RENDER_PIXELS_PER_M,
    hud: bool = True,
) -> jax.Array:
    """(H, W, 3) uint8 bird's-eye view (SPEC §1–5), 240 × 480 by default: x from ``s -
    behind_m`` to ``s + ahead_m``, y up over ``±half_width_m``; keywords are static."""
    height = round(2 * half_width_m * pixels_per_m)
    width = round((behind_m + ahead_m) * pixels_per_m)
    pixel = 1.0 / pixels_per_m
    x = state.ego.s - behind_m + (jnp.arange(width, dtype=jnp.float32) + 0.5) * pixel  # (W,)
    y = half_width_m - (jnp.arange(height, dtype=jnp.float32) + 0.5) * pixel  # (H,)
    xy = jnp.stack(jnp.broadcast_arrays(x[None, :], y[:, None]), axis=-1)  # (H, W, 2)
    image = _draw_map(xy, params, static, pixel)
    image = _draw_ego(image, xy, state, params)
    image = _draw_pedestrians(image, xy, state, params, pixel)
    if hud:
        image = _draw_hud(image, *_hud_layout(state, params, static))
    return image
