"""Gymnasium environments over the JAX simulator (SPEC §1–5).

The pure JAX env (:class:`~drqn_jax.env.urban.UrbanPedestrians`) speaks the
gymnax contract; this module puts it behind Gymnasium's API so that any
Gymnasium-speaking library can drive it, with NumPy in and out:

* :class:`UrbanPedestriansGymEnv` — a :class:`gymnasium.Env` (one episode at a
  time, no auto-reset; ``render_mode="rgb_array"``);
* :class:`UrbanPedestriansVectorEnv` — a native :class:`gymnasium.vector.VectorEnv`:
  one jitted, ``vmap``-ed call per step for all sub-environments, with
  ``AutoresetMode.NEXT_STEP`` (default), ``SAME_STEP`` or ``DISABLED``;
* :func:`register_gymnasium_envs` — registers ``drqn_jax/<id>`` for every id of
  :func:`drqn_jax.registered_envs` (``import drqn_jax`` calls it), so
  ``gymnasium.make("drqn_jax/UrbanPedestrians-v0", max_steps=300)`` and
  ``gymnasium.make_vec("drqn_jax/UrbanPedestrians-v0", num_envs=64)`` work;
  extra keyword arguments go to :func:`drqn_jax.make`.

Observation (SPEC §4), a ``Dict``:

* ``grid``: ``Box`` (45, 30, 4) float32 with per-channel bounds: occupancy
  [0, 1], relative heading [−1, 1], speed [0, b], semantics [0, 1], where b is
  the largest value the speed channel can take under the env's parameters
  (:func:`grid_speed_high`; the JAX space leaves it unbounded);
* ``speed``: ``Box`` shape **(1,)** float32 in [0, max_vehicle_speed / v_ref]
  (the JAX observation's ``()`` scalar as a length-1 vector, the shape common
  libraries — ``FlattenObservation``, Stable-Baselines3's ``MultiInputPolicy`` —
  expect of a Box);
* ``last_action``: ``Discrete(5)``: the previous action 0–3, or
  :data:`NO_ACTION_YET` (4) at episode start. The JAX observation writes −1
  there; Gymnasium's space starts at 0 because Stable-Baselines3 and most
  one-hot encoders take only such spaces (:func:`gymnasium_last_action`).

Actions: ``Discrete(4)`` (0 accelerate, 1 slow_down, 2 brake, 3 steer; paper
§IV-B). Termination and truncation are the JAX env's (``step_env``: collision or
goal; ``max_steps``). ``info`` holds ``collision``, ``goal`` (Python bools),
``ttc`` (s, ``inf`` when none), ``distance`` (m), ``speed`` (m/s, unnormalised)
(NumPy float32) and ``time`` (steps, NumPy int32); the vector env batches them
into (N,) arrays of bool, float32 and int32.

Keys. Every reset draws one JAX key from Gymnasium's ``np_random`` (so
``reset(seed=s)`` is reproducible and an unseeded reset continues the stream);
it splits into the key that draws the new episode and the key the env holds;
every step splits the held key. The vector env keeps one ``np_random`` per
sub-environment, seeded like :class:`gymnasium.vector.SyncVectorEnv` seeds its
envs (``seed + i``), and auto-resets from that sub-environment's stream, so
sub-environment ``i`` behaves exactly like ``gymnasium.make(id)`` reset with
``seed + i`` and driven by the same actions, whatever ``num_envs`` is.

Rendering (``render_mode="rgb_array"``): ``render()`` returns :func:`render_frame`,
the bird's-eye view that :mod:`drqn_jax.env.viewer` draws in pure JAX — a (240, 480, 3)
uint8 frame of the map, the ego, the pedestrians coloured by behaviour and a HUD with
the step, the speed (km/h), the last action and the TTC, in the palette the rerun
recordings share; the vector env returns a tuple of N frames from one vmapped call.

The jitted functions are built once per static env (a module-level cache keyed
on the hashable JAX env) and take ``EnvParams`` as arguments, so creating
more envs, or the realistic preset beside the paper's, compiles nothing new.
"""

from __future__ import annotations

import functools
from typing import Any, ClassVar, NamedTuple, SupportsFloat

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from drqn_jax.env import viewer
from drqn_jax.env.params import SPEED_RELATIVE, EnvParams
from drqn_jax.env.state import NO_ACTION, NUM_ACTIONS, EnvState, Observation
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.env.viewer import (
    RENDER_AHEAD_M,
    RENDER_BEHIND_M,
    RENDER_HALF_WIDTH_M,
    RENDER_PIXELS_PER_M,
)
from drqn_jax.programs import cached_program
from drqn_jax.registry import make as make_jax_env
from drqn_jax.registry import registered_envs

__all__ = [
    "NAMESPACE",
    "NO_ACTION_YET",
    "RENDER_AHEAD_M",
    "RENDER_BEHIND_M",
    "RENDER_HALF_WIDTH_M",
    "RENDER_PIXELS_PER_M",
    "UrbanPedestriansGymEnv",
    "grid_speed_high",
    "gymnasium_ids",
    "gymnasium_last_action",
    "gymnasium_observation_space",
    "register_gymnasium_envs",
    "render_frame",
]

NAMESPACE = "drqn_jax"
NO_ACTION_YET = NUM_ACTIONS  # Gymnasium's ``last_action`` at episode start
SPEED_CHANNEL = 2  # the grid channel without a fixed upper bound (SPEC §4)
# Float32 rounding margin on the bounds derived from EnvParams (relative).
_BOUND_MARGIN = 1e-5


# --- spaces -----------------------------------------------------------------
def _round_up_f32(x: float) -> np.float32:
    """``x`` widened by the float32 rounding margin, as float32."""
    return np.float32(x * (1.0 + _BOUND_MARGIN) if x > 0 else x)


def grid_speed_high(params: EnvParams) -> float:
    """Largest value of the grid's speed channel (SPEC §4, ch2) under ``params``.

    ``speed_channel = "pedestrian"``: a pedestrian walks at most
    ``ped_speed_max``, so ``ped_speed_max / speed_norm_pedestrian``.
    ``"relative"``: the ego drives at most ``max_vehicle_speed`` along +x, so
    ``(max_vehicle_speed + ped_speed_max + δ) / speed_norm_relative``, where δ
    bounds the float32 error of a velocity measured as a displacement over
    ``dt`` at world coordinates up to the goal plus the spawn and despawn
    ranges. Both carry a relative float32 rounding margin of 1e-5.
    """
    ped_max = float(params.ped_speed_max)
    if int(params.speed_channel) == SPEED_RELATIVE:
        extent = abs(float(params.goal_x)) + float(params.spawn_max) + float(params.despawn_ahead)
        delta = 2.0 * extent * float(np.finfo(np.float32).eps) / float(params.dt)
        bound = (float(params.max_vehicle_speed) + ped_max + delta) / float(
            params.speed_norm_relative
        )
    else:
        bound = ped_max / float(params.speed_norm_pedestrian)
    return float(_round_up_f32(bound))


def gymnasium_observation_space(env: UrbanPedestrians, params: EnvParams) -> spaces.Dict:
    """The Gymnasium observation space of one env (SPEC §4).

    Bounds are the JAX env's :meth:`~UrbanPedestrians.observation_space`, with
    the speed channel's open upper bound replaced by :func:`grid_speed_high`
    and the ego speed's by its float32-rounded value (margin 1e-5).

    Returns:
        ``Dict(grid=Box((rows, cols, 4), float32), speed=Box((1,), float32),
        last_action=Discrete(5))``.
    """
    jax_space = env.observation_space(params)
    grid = jax_space.spaces["grid"]
    low = np.array(np.broadcast_to(np.asarray(grid.low, np.float32), grid.shape))
    high = np.array(np.broadcast_to(np.asarray(grid.high, np.float32), grid.shape))
    high[..., SPEED_CHANNEL] = np.minimum(high[..., SPEED_CHANNEL], grid_speed_high(params))
    if not np.all(np.isfinite(low)) or not np.all(np.isfinite(high)):
        raise ValueError("grid bounds must be finite: a channel has no known bound")
    speed = jax_space.spaces["speed"]
    return spaces.Dict(
        {
            "grid": spaces.Box(low, high, grid.shape, np.float32),
            "speed": spaces.Box(
                np.float32(speed.low), _round_up_f32(float(speed.high)), (1,), np.float32
            ),
            "last_action": spaces.Discrete(NUM_ACTIONS + 1),
        }
    )


def gymnasium_last_action(last_action: np.ndarray) -> np.ndarray:
    """The JAX ``last_action`` (any shape; −1 before the first action, else 0–3) as
    Gymnasium's ``Discrete(5)`` value: the action itself, or :data:`NO_ACTION_YET`."""
    return np.where(last_action == NO_ACTION, NO_ACTION_YET, last_action)


def numpy_observation(obs: Observation) -> dict[str, Any]:
    """NumPy (fresh, writable) observation dict; leading batch axes are kept.

    ``grid`` (..., rows, cols, 4) float32, ``speed`` (..., 1) float32,
    ``last_action`` (...) int64 (a NumPy scalar when unbatched), in
    :func:`gymnasium_last_action`'s encoding.
    """
    last_action = gymnasium_last_action(np.array(obs.last_action, np.int64))
    return {
        "grid": np.array(obs.grid, np.float32),
        "speed": np.array(obs.speed, np.float32)[..., None],
        "last_action": last_action[()] if last_action.ndim == 0 else last_action,
    }


def invalid_action(action: Any, space: spaces.Space) -> ValueError:
    return ValueError(
        f"invalid action {action!r}: not an element of the action space {space} "
        "(0 accelerate, 1 slow_down, 2 brake, 3 steer)"
    )


def space_contains(space: spaces.Space, x: Any) -> bool:
    try:
        return bool(space.contains(x))
    except Exception:  # e.g. an object NumPy cannot compare
        return False


# --- rendering --------------------------------------------------------------
def render_frame(
    env: UrbanPedestrians, state: EnvState, params: EnvParams, **view: Any
) -> jax.Array:
    """:func:`drqn_jax.env.viewer.render_frame` of ``env``'s state (SPEC §1–5), pure JAX:
    the bird's-eye view with the step, speed, last action and TTC; ``view`` takes
    viewer's keyword arguments (``behind_m``, ``pixels_per_m``, ``hud``, …).

    Returns:
        (H, W, 3) uint8, 240 × 480 by default.
    """
    return viewer.render_frame(state, params, env.static, **view)


# --- compiled functions, one set per static env ------------------------------
class _SingleFns(NamedTuple):
    reset: Any  # (key_data (w,) uint32, params) -> (key_data, obs, state)
    step: Any  # (key_data, state, action, params) -> (key_data, obs, state, r, term, trunc, info)
    render: Any  # (state, params) -> (H, W, 3) uint8


@cached_program
def key_data_shape() -> tuple[int, ...]:
    """Shape of one key's raw data under JAX's default PRNG implementation ((2,) for threefry)."""
    return jax.eval_shape(lambda: jax.random.key_data(jax.random.key(0))).shape


def draw_key_data(rng: np.random.Generator) -> np.ndarray:
    """One JAX key's raw data (uint32 words) drawn from a NumPy generator."""
    return rng.integers(0, 2**32, size=key_data_shape(), dtype=np.uint32)


def _split(key_data: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Split raw key data into (kept key data, a typed key to use now)."""
    kept, use = jax.random.split(jax.random.wrap_key_data(key_data))
    return jax.random.key_data(kept), use


def single_reset(
    env: UrbanPedestrians, key_data: jax.Array, params: EnvParams
) -> tuple[jax.Array, Observation, EnvState]:
    """One env's reset from raw key data (``key_data_shape()``): ``(the key data kept
    for the next call, obs, state)``."""
    held, reset_key = _split(key_data)
    obs, state = env.reset_env(reset_key, params)
    return held, obs, state


def single_step(
    env: UrbanPedestrians, key_data: jax.Array, state: EnvState, action: jax.Array, params
) -> tuple[jax.Array, Observation, EnvState, jax.Array, jax.Array, jax.Array, dict]:
    """One env's step (no auto-reset: ``step_env``) from raw key data: ``(the key data
    kept for the next call, obs, state, reward, terminated, truncated, info)``."""
    held, step_key = _split(key_data)
    obs, state, reward, terminated, truncated, info = env.step_env(step_key, state, action, params)
    return held, obs, state, reward, terminated, truncated, info


def _packed_step(env: UrbanPedestrians, key_data, state, action, params):
    """:func:`single_step` with what the host reads as two arrays: the grid and one
    float32 vector of every scalar (speed, last action, reward, flags, info values in
    sorted key order). Each host transfer costs tens of µs; one step had fourteen."""
    held, obs, state, reward, terminated, truncated, info = single_step(
        env, key_data, state, action, params
    )
    scalars = [obs.speed, obs.last_action, reward, terminated, truncated]
    scalars += [info[k] for k in sorted(info)]
    packed = jnp.stack([jnp.asarray(x, jnp.float32).reshape(()) for x in scalars])
    return held, state, obs.grid, packed


def _unpack_step(
    dtypes: tuple[tuple[str, Any], ...], grid: np.ndarray, packed: np.ndarray
) -> tuple:
    """The host side of :func:`_packed_step`: ``(obs, reward, terminated, truncated, info)``
    with every value at its own dtype (``dtypes``: :func:`_info_dtypes`; exact: the
    packed values are float32 reals, small integers and flags)."""
    speed, last_action, reward, terminated, truncated = packed[:5]
    info = {
        k: bool(v) if dtype == np.bool_ else np.asarray(v).astype(dtype)[()]
        for (k, dtype), v in zip(dtypes, packed[5:], strict=True)
    }
    obs = numpy_observation(Observation(grid=grid, speed=speed, last_action=last_action))
    return obs, float(reward), bool(terminated), bool(truncated), info


def _info_dtypes(env: UrbanPedestrians, params: EnvParams) -> tuple[tuple[str, Any], ...]:
    """The info dict's keys (sorted) and NumPy dtypes of one step (no computation)."""
    key_data = np.zeros(key_data_shape(), np.uint32)
    state = jax.eval_shape(lambda: single_reset(env, key_data, params)[2])
    out = jax.eval_shape(lambda s: single_step(env, key_data, s, jnp.int32(0), params), state)
    return tuple((k, np.dtype(v.dtype)) for k, v in sorted(out[-1].items()))


@cached_program
def _single_fns(env: UrbanPedestrians) -> _SingleFns:
    """Jitted reset/step/render of one env, built once per static env."""
    return _SingleFns(
        reset=jax.jit(functools.partial(single_reset, env)),
        step=jax.jit(functools.partial(_packed_step, env)),
        render=jax.jit(functools.partial(render_frame, env)),
    )


# --- the single env ---------------------------------------------------------
class UrbanPedestriansGymEnv(gymnasium.Env[dict[str, Any], Any]):
    """The urban-pedestrian env (paper §V-D, SPEC §1–5) as a :class:`gymnasium.Env`.

    Args:
        env_id: a :func:`drqn_jax.registered_envs` id (``"UrbanPedestrians-v0"``:
            the paper's settings; ``"UrbanPedestriansRealistic-v0"``).
        render_mode: ``None`` or ``"rgb_array"`` (:func:`render_frame`).
        **overrides: any :func:`drqn_jax.make` override, e.g. ``max_steps=300``.

    Attributes:
        jax_env, params: the JAX env and its ``EnvParams``.
        observation_space: see the module docstring; action_space: ``Discrete(4)``.

    ``step`` before ``reset`` raises :class:`gymnasium.error.ResetNeeded` (the
    env is registered without Gymnasium's ``OrderEnforcing`` and
    ``PassiveEnvChecker`` wrappers: it enforces the order itself and passes
    ``check_env``). Stepping past the end of an episode continues the
    simulation without resetting; call ``reset``.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}  # 1/dt

    def __init__(
        self, env_id: str = "UrbanPedestrians-v0", render_mode: str | None = None, **overrides: Any
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode={render_mode!r} is not supported; "
                f"render modes: {self.metadata['render_modes']}"
            )
        self.env_id = env_id
        self.jax_env, params = make_jax_env(env_id, **overrides)
        self.params = params
        self._device_params = jax.device_put(params)
        self.render_mode = render_mode
        self.observation_space = gymnasium_observation_space(self.jax_env, params)
        self.action_space = spaces.Discrete(NUM_ACTIONS)
        self._fns = _single_fns(self.jax_env)
        self._info_dtypes = _info_dtypes(self.jax_env, params)
        self._key_data: jax.Array | None = None
        self._state: EnvState | None = None

    @property
    def state(self) -> EnvState | None:
        """The current JAX ``EnvState`` (``None`` before the first reset)."""
        return self._state

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode; the JAX key is drawn from ``self.np_random``.

        Args:
            seed: reseeds ``np_random`` when given. ``options`` is accepted and unused.
        Returns:
            ``(observation, {})``.
        """
        super().reset(seed=seed)
        key_data = draw_key_data(self.np_random)
        self._key_data, obs, self._state = self._fns.reset(key_data, self._device_params)
        return numpy_observation(jax.device_get(obs)), {}

    def step(self, action: Any) -> tuple[dict[str, Any], SupportsFloat, bool, bool, dict[str, Any]]:
        """One decision step (0.1 s) with ``action`` in ``Discrete(4)``.

        Returns:
            ``(observation, reward, terminated, truncated, info)``: reward a
            Python float in [−10, 1], the flags Python bools, info as in the
            module docstring.
        Raises:
            ValueError: ``action`` is not in the action space.
            ResetNeeded: called before ``reset``.
        """
        if isinstance(action, jax.Array):
            action = np.asarray(action)
        if not space_contains(self.action_space, action):
            raise invalid_action(action, self.action_space)
        if self._state is None:
            raise ResetNeeded("Cannot call UrbanPedestriansGymEnv.step before reset")
        out = self._fns.step(self._key_data, self._state, np.int32(action), self._device_params)
        self._key_data, self._state, grid, packed = out
        # Flags come back as Python bools (SyncVectorEnv batches those, not np.bool_).
        return _unpack_step(self._info_dtypes, *jax.device_get((grid, packed)))

    def render(self) -> np.ndarray | None:
        """(240, 480, 3) uint8 bird's-eye view (:func:`render_frame`) for ``"rgb_array"``."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() called without a render_mode; e.g. "
                'gymnasium.make("drqn_jax/UrbanPedestrians-v0", render_mode="rgb_array")'
            )
            return None
        if self._state is None:
            raise ResetNeeded("Cannot call UrbanPedestriansGymEnv.render before reset")
        return np.array(self._fns.render(self._state, self._device_params))


# --- registration -----------------------------------------------------------
def gymnasium_ids() -> tuple[str, ...]:
    """The Gymnasium ids: ``drqn_jax/<id>`` for every :func:`drqn_jax.registered_envs` id."""
    return tuple(f"{NAMESPACE}/{env_id}" for env_id in registered_envs())


def register_gymnasium_envs() -> tuple[str, ...]:
    """Register :func:`gymnasium_ids` with Gymnasium (idempotent: present ids are kept).

    Each id has ``entry_point`` :class:`UrbanPedestriansGymEnv`,
    ``vector_entry_point`` :class:`UrbanPedestriansVectorEnv` and
    ``kwargs={"env_id": <drqn_jax id>}``; ``order_enforce`` and the passive
    checker are off (the env enforces reset-before-step and passes
    ``check_env``), so ``gymnasium.make`` returns the env itself.

    Returns:
        the ids.
    """
    for env_id in registered_envs():
        gym_id = f"{NAMESPACE}/{env_id}"
        if gym_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=gym_id,
            entry_point=f"{__name__}:UrbanPedestriansGymEnv",
            vector_entry_point="drqn_jax.interop.gymnasium_vector:UrbanPedestriansVectorEnv",
            kwargs={"env_id": env_id},
            order_enforce=False,
            disable_env_checker=True,
        )
    return gymnasium_ids()
