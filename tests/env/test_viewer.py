"""How the env is drawn (drqn_jax/env/viewer.py): the raster, the HUD, the one palette.

Scenes are built by hand from a reset state: pedestrians moved to known pixels
(the others far behind), the ego's speed, step and last action set, so each
check knows what it must see.
"""

from __future__ import annotations

import ast
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax
from drqn_jax.env import viewer
from drqn_jax.env.collision import time_to_collision
from drqn_jax.env.road_map import lane_centre_y
from drqn_jax.env.state import ACCELERATE, ACTIONS, BRAKE, JAYWALKING
from drqn_jax.interop import gymnasium_env, recording

PPM = viewer.RENDER_PIXELS_PER_M
HEIGHT, WIDTH = 240, 480
FAR = -1000.0  # x of a pedestrian out of every view


@pytest.fixture(scope="module")
def env_params():
    return drqn_jax.make("UrbanPedestrians-v0")


@pytest.fixture(scope="module")
def fns(env_params):
    """Jitted render, batched render and HUD of the env's static settings."""
    env, _ = env_params
    render = partial(viewer.render_frame, static=env.static)
    hud = partial(viewer.hud_glyphs, static=env.static)
    return {
        "render": jax.jit(render),
        "render_batch": jax.jit(jax.vmap(render, in_axes=(0, None))),
        "render_no_hud": jax.jit(partial(render, hud=False)),
        "hud": jax.jit(hud),
    }


@pytest.fixture(scope="module")
def start(env_params):
    """A reset state with every pedestrian far behind the ego (none in view)."""
    env, params = env_params
    _, state = jax.jit(env.reset_env)(jax.random.key(0), params)
    peds = state.pedestrians
    far = jnp.broadcast_to(jnp.array([FAR, 5.0], jnp.float32), peds.position.shape)
    return state.replace(pedestrians=peds.replace(position=far, velocity=jnp.zeros_like(far)))


def with_ego(state, *, v=None, time=None, last_action=None):
    ego = state.ego if v is None else state.ego.replace(v=jnp.float32(v))
    return state.replace(
        ego=ego,
        time=state.time if time is None else jnp.int32(time),
        last_action=state.last_action if last_action is None else jnp.int32(last_action),
    )


def with_pedestrian(state, xy, behaviour, visible=True, i=0):
    peds = state.pedestrians
    return state.replace(
        pedestrians=peds.replace(
            position=peds.position.at[i].set(jnp.asarray(xy, jnp.float32)),
            behaviour=peds.behaviour.at[i].set(behaviour),
            visible=peds.visible.at[i].set(visible),
        )
    )


def pixel_centre(state, row: int, col: int) -> np.ndarray:
    """World (x, y) of a pixel's centre, computed as render_frame computes it."""
    s = np.float32(state.ego.s)
    x = s - np.float32(viewer.RENDER_BEHIND_M) + np.float32((col + 0.5) / PPM)
    y = np.float32(viewer.RENDER_HALF_WIDTH_M) - np.float32((row + 0.5) / PPM)
    return np.array([x, y], np.float32)


def read_hud(frame: np.ndarray, lines: int = viewer.HUD_LINES) -> list[str]:
    """The HUD's text read back from the pixels: each character cell's ink (any HUD
    text or action colour), sampled at the font's pixels, matched against FONT."""
    inks = [viewer.HUD_TEXT_COLOUR, *viewer.ACTION_COLOURS]
    ink = np.zeros(frame.shape[:2], bool)
    for colour in inks:
        ink |= np.all(frame == np.array(colour, np.uint8), axis=-1)
    s, m = viewer.HUD_SCALE, viewer._HUD_MARGIN_PX
    rows, cols = viewer.FONT.shape[1:]
    out = []
    for k in range(lines):
        top = m + k * (rows * s + m)
        text = ""
        for c in range(viewer.HUD_LINE_LENGTH):
            left = m + c * (cols + 1) * s
            cell = ink[top : top + rows * s : s, left : left + cols * s : s]
            if cell.shape != (rows, cols):
                break
            match = [g for g, bitmap in enumerate(viewer.FONT) if np.array_equal(bitmap, cell)]
            assert len(match) == 1, f"line {k}, character {c}: no single glyph matches"
            text += viewer.GLYPHS[match[0]]
        out.append(text.rstrip())
    return out


# --- the frame -------------------------------------------------------------------


def test_frame_is_240_by_480_uint8(env_params, fns, start):
    frame = fns["render"](start, env_params[1])
    assert frame.shape == (HEIGHT, WIDTH, 3) and frame.dtype == jnp.uint8


def test_other_sizes_crop_the_hud(env_params, start):
    env, params = env_params
    small = jax.jit(  # one program (op by op: about 200 small ones)
        lambda s, p: viewer.render_frame(s, p, env.static, half_width_m=2.0, pixels_per_m=2)
    )(start, params)
    assert small.shape == (8, 120, 3) and small.dtype == jnp.uint8


@pytest.mark.parametrize("behaviour", range(3))
def test_a_pedestrian_is_an_outlined_disc_of_the_minimum_radius(env_params, fns, start, behaviour):
    """A 0.3 m pedestrian is 2.4 px at 8 px/m; it is drawn with at least
    MIN_PED_RADIUS_PX (every pixel centre closer than that has its behaviour's
    colour), and the next pixel ring is the dark outline."""
    _, params = env_params
    row, col = 170, 300  # the right sidewalk, ahead of the ego, below the HUD
    state = with_pedestrian(start, pixel_centre(start, row, col), behaviour)
    frame = np.asarray(fns["render"](state, params))
    r = viewer.MIN_PED_RADIUS_PX
    dy, dx = np.mgrid[-r - 2 : r + 3, -r - 2 : r + 3]
    d2 = dy * dy + dx * dx
    patch = frame[row - r - 2 : row + r + 3, col - r - 2 : col + r + 3]
    fill = patch[d2 < r * r]
    assert len(fill) >= 69  # the pixel centres of a disc of radius 5 px (25 excluded)
    assert np.all(fill == viewer.BEHAVIOUR_COLOURS[behaviour])
    ring = patch[(d2 > r * r) & (d2 < (r + 1) ** 2)]
    assert np.all(ring == viewer.PED_OUTLINE_COLOUR)
    assert not np.any(np.all(patch[d2 > (r + 1) ** 2] == viewer.BEHAVIOUR_COLOURS[behaviour], -1))


def test_an_occluded_pedestrian_is_faded(env_params, fns, start):
    _, params = env_params
    row, col = 170, 300
    xy = pixel_centre(start, row, col)
    seen = np.asarray(fns["render"](with_pedestrian(start, xy, JAYWALKING), params))
    hidden = np.asarray(fns["render"](with_pedestrian(start, xy, JAYWALKING, False), params))
    empty = np.asarray(fns["render"](start, params))
    colour = np.array(viewer.BEHAVIOUR_COLOURS[JAYWALKING], np.float64)
    a = viewer.OCCLUDED_ALPHA / 255
    expected = np.round(empty[row, col] * (1 - a) + colour * a)
    np.testing.assert_array_equal(hidden[row, col], expected)
    assert tuple(seen[row, col]) == viewer.BEHAVIOUR_COLOURS[JAYWALKING]
    outline = (row, col + viewer.MIN_PED_RADIUS_PX + 1)  # 1 px past the fill, both outlined
    assert tuple(hidden[outline]) == tuple(seen[outline]) == viewer.PED_OUTLINE_COLOUR


def test_the_ego_turns_the_collision_colour(env_params, fns, start):
    _, params = env_params
    moving = with_ego(start, v=5.0)
    ego_row = round((viewer.RENDER_HALF_WIDTH_M + 1.75) * PPM)
    ego_col = round(viewer.RENDER_BEHIND_M * PPM)
    assert tuple(np.asarray(fns["render"](moving, params))[ego_row, ego_col]) == viewer.EGO_COLOUR
    on_ego = [moving.ego.s + 2.0, lane_centre_y(params)]  # the front of the box: a collision
    hit = np.asarray(fns["render"](with_pedestrian(moving, on_ego, JAYWALKING), params))
    assert tuple(hit[ego_row, ego_col]) == viewer.EGO_COLLISION_COLOUR


# --- the HUD ---------------------------------------------------------------------


def test_hud_text_of_a_chosen_state(env_params, fns, start):
    """Step 12, 10 m/s = 36.0 km/h, last action accelerate; a pedestrian standing in
    the lane 14.5 m ahead of the box's reach closes at 10 m/s: TTC 1.5 s (SPEC §5)."""
    env, params = env_params
    state = with_ego(start, v=10.0, time=12, last_action=ACCELERATE)
    assert np.float32(params.ego_length) == 4.5 and np.float32(params.ped_radius) == 0.3
    ahead = [state.ego.s + 2.25 + 0.3 + 14.5, lane_centre_y(params)]
    state = with_pedestrian(state, ahead, JAYWALKING)
    ttc = time_to_collision(state.ego, state.pedestrians, params, env.static)
    np.testing.assert_allclose(ttc, 1.5, atol=1e-6)
    glyphs = fns["hud"](state, params)
    assert glyphs.shape == (viewer.HUD_LINES, viewer.HUD_LINE_LENGTH) == (2, 23)
    assert glyphs.dtype == jnp.int32
    assert viewer.hud_text(glyphs) == "step 12  36.0 km/h  accelerate  TTC 1.5 s"


def test_hud_text_without_action_or_ttc(env_params, fns, start):
    """At reset: no action yet, standing (TTC infinite), as "-"; large values keep
    every digit."""
    _, params = env_params
    assert viewer.hud_text(fns["hud"](start, params)) == "step 0  0.0 km/h  -  TTC -"
    state = with_ego(start, v=13.75, time=1000, last_action=BRAKE)  # no one in view: TTC inf
    assert viewer.hud_text(fns["hud"](state, params)) == "step 1000  49.5 km/h  brake  TTC -"


def test_the_frame_shows_the_hud_text(env_params, fns, start):
    """The pixels of the HUD read back (through FONT) as hud_text's lines."""
    _, params = env_params
    for state in (start, with_ego(start, v=10.0, time=12, last_action=ACCELERATE)):
        frame = np.asarray(fns["render"](state, params))
        lines = read_hud(frame)
        assert "  ".join(lines) == viewer.hud_text(fns["hud"](state, params))


def test_hud_pixels_follow_the_speed(env_params, fns, start):
    """Changing only the speed changes the HUD's pixels and nothing else."""
    _, params = env_params
    slow = np.asarray(fns["render"](with_ego(start, v=10.0), params))
    fast = np.asarray(fns["render"](with_ego(start, v=12.0), params))
    m = viewer._HUD_MARGIN_PX
    band = viewer.HUD_LINES * (viewer.FONT.shape[1] * viewer.HUD_SCALE + m) + m
    assert not np.array_equal(slow[:band], fast[:band])
    np.testing.assert_array_equal(slow[band:], fast[band:])
    a = fns["render_no_hud"](with_ego(start, v=10.0), params)
    b = fns["render_no_hud"](with_ego(start, v=12.0), params)
    np.testing.assert_array_equal(a, b)


def test_the_font_covers_the_hud():
    assert viewer.FONT.shape == (len(viewer.GLYPHS), 7, 5)
    assert len({b.tobytes() for b in viewer.FONT}) == len(viewer.GLYPHS)  # all distinct
    assert set("".join(ACTIONS) + "step km/h TTC s 0123456789.-") <= set(viewer.GLYPHS)


# --- jit, vmap, the backends ---------------------------------------------------------


def test_a_batch_renders_as_each_state_alone(env_params, fns):
    env, params = env_params
    states = []
    for seed in (1, 2):
        _, state = env.reset_env(jax.random.key(seed), params)
        for k in jax.random.split(jax.random.key(seed), 15):
            _, state, *_ = env.step_env(k, state, jnp.int32(ACCELERATE), params)
        states.append(state)
    batch = jax.tree.map(lambda *xs: jnp.stack(xs), *states)
    frames = np.asarray(fns["render_batch"](batch, params))
    assert frames.shape == (2, HEIGHT, WIDTH, 3)
    for i, state in enumerate(states):
        np.testing.assert_array_equal(frames[i], np.asarray(fns["render"](state, params)))
    assert not np.array_equal(frames[0], frames[1])


def test_gymnasium_renders_the_viewer_frame(env_params, fns):
    env = gymnasium_env.UrbanPedestriansGymEnv(render_mode="rgb_array")
    env.reset(seed=3)
    for _ in range(5):
        env.step(ACCELERATE)
    np.testing.assert_array_equal(env.render(), fns["render"](env.state, env.params))
    assert viewer.hud_text(fns["hud"](env.state, env.params)).startswith("step 5  ")


def rgb_literals(module) -> list[str]:
    """The 3-integer tuple or list literals in a module's code (docstrings aside)."""
    tree = ast.parse(Path(module.__file__).read_text())
    return [
        ast.unparse(node)
        for node in ast.walk(tree)
        if isinstance(node, ast.Tuple | ast.List)
        and len(node.elts) == 3
        and all(isinstance(e, ast.Constant) and type(e.value) is int for e in node.elts)
    ]


def test_one_palette():
    """recording and gymnasium_env take their colours and view from viewer, and
    neither module spells an RGB colour of its own."""
    for name in ("BEHAVIOUR_COLOURS", "OCCLUDED_ALPHA", "EGO_COLOUR", "EGO_COLLISION_COLOUR"):
        assert getattr(recording, name) is getattr(viewer, name)
    assert recording.hud_text is viewer.hud_text
    for name in ("RENDER_AHEAD_M", "RENDER_BEHIND_M", "RENDER_HALF_WIDTH_M", "RENDER_PIXELS_PER_M"):
        assert not hasattr(gymnasium_env, name)  # the view is viewer's alone
    assert rgb_literals(viewer)  # the check sees the palette where it is
    assert rgb_literals(recording) == [] and rgb_literals(gymnasium_env) == []
