"""Gymnasium env over the JAX simulator (SPEC §1–5), NumPy in and out, as ``drqn_jax/<id>``.
``speed`` has shape (1,) and ``last_action`` is ``Discrete(5)`` (:data:`NO_ACTION_YET` for
−1): SB3-style libraries need Box shapes and spaces from 0. Resets draw a JAX key from
``np_random``; steps split the held key."""

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
from drqn_jax.programs import cached_program
from drqn_jax.registry import make as make_jax_env
from drqn_jax.registry import registered_envs

NAMESPACE = "drqn_jax"
NO_ACTION_YET = NUM_ACTIONS  # Gymnasium's ``last_action`` at episode start
SPEED_CHANNEL = 2  # the grid channel without a fixed upper bound (SPEC §4)
_BOUND_MARGIN = 1e-5  # relative float32 rounding margin on bounds from EnvParams


def _round_up_f32(x: float) -> np.float32:
    return np.float32(x * (1.0 + _BOUND_MARGIN) if x > 0 else x)


def grid_speed_high(params: EnvParams) -> float:
    """Largest grid speed-channel value (SPEC §4); ``"relative"`` adds δ, the float32 error
    of a displacement over ``dt`` at the largest world coordinates."""
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
    """The JAX env's observation space (SPEC §4) as a ``Dict`` with finite float32 bounds."""
    jax_space = env.observation_space(params)
    grid = jax_space.spaces["grid"]
    low = np.array(np.broadcast_to(np.asarray(grid.low, np.float32), grid.shape))
    high = np.array(np.broadcast_to(np.asarray(grid.high, np.float32), grid.shape))
    high[..., SPEED_CHANNEL] = np.minimum(high[..., SPEED_CHANNEL], grid_speed_high(params))
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


def numpy_observation(obs: Observation) -> dict[str, Any]:
    """Fresh NumPy observation dict, batch axes kept (``speed`` (..., 1)), ``last_action`` in
    ``Discrete(5)`` (−1 becomes :data:`NO_ACTION_YET`)."""
    last_action = np.array(obs.last_action, np.int64)
    last_action = np.where(last_action == NO_ACTION, NO_ACTION_YET, last_action)
    return {
        "grid": np.array(obs.grid, np.float32),
        "speed": np.array(obs.speed, np.float32)[..., None],
        "last_action": last_action[()] if last_action.ndim == 0 else last_action,
    }


def valid_action(action: Any, space: spaces.Space) -> Any:
    """``action`` (a JAX array as NumPy); a ValueError unless ``space`` contains it."""
    if isinstance(action, jax.Array):
        action = np.asarray(action)
    try:
        valid = bool(space.contains(action))
    except Exception:  # e.g. an object NumPy cannot compare
        valid = False
    if not valid:
        raise ValueError(
            f"invalid action {action!r}: not an element of the action space {space} "
            "(0 accelerate, 1 slow_down, 2 brake, 3 steer)"
        )
    return action


@cached_program
def key_data_shape() -> tuple[int, ...]:
    """Shape of one key's raw data under JAX's default PRNG ((2,) for threefry)."""
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
    """One env's reset from raw key data: ``(held key data, obs, state)``."""
    held, reset_key = _split(key_data)
    return held, *env.reset_env(reset_key, params)


def single_step(
    env: UrbanPedestrians, key_data: jax.Array, state: EnvState, action: jax.Array, params
) -> tuple[jax.Array, Observation, EnvState, jax.Array, jax.Array, jax.Array, dict]:
    """One env's ``step_env`` from raw key data, the held key data first. The info holds
    the decision's scalars (SPEC §5); a k-tick decision's per-tick ``ticks`` stay in JAX."""
    held, step_key = _split(key_data)
    obs, state, reward, terminated, truncated, info = env.step_env(step_key, state, action, params)
    info = {k: v for k, v in info.items() if k != "ticks"}
    return held, obs, state, reward, terminated, truncated, info


#: Restarts computed per pass of :func:`_restart_where` (a step with more takes several).
RESETS_PER_PASS = 8


def _restart_where(
    env: UrbanPedestrians,
    restart: jax.Array,
    reset_key_data: jax.Array,
    held: jax.Array,
    obs: Observation,
    states: EnvState,
    params: EnvParams,
) -> tuple[jax.Array, Observation, EnvState]:
    """Fresh episodes where ``restart`` (N,) is set, :data:`RESETS_PER_PASS` at a time (no
    pass without one); each uses only its own key, so the bits do not depend on the count."""
    n = restart.shape[0]
    k = min(n, RESETS_PER_PASS)
    reset = jax.vmap(functools.partial(single_reset, env), in_axes=(0, None))

    def reset_some(carry: tuple) -> tuple:
        pending, *trees = carry
        index = jnp.nonzero(pending, size=k, fill_value=n)[0]  # (k,); n: no env, dropped
        fresh = reset(reset_key_data[jnp.minimum(index, n - 1)], params)

        def put(into: jax.Array, rows: jax.Array) -> jax.Array:
            return into.at[index].set(rows, mode="drop")

        return put(pending, jnp.zeros(k, bool)), *jax.tree.map(put, tuple(trees), fresh)

    _, *out = jax.lax.while_loop(lambda c: c[0].any(), reset_some, (restart, held, obs, states))
    return tuple(out)


def _batch_step(
    env: UrbanPedestrians,
    same_step: bool,
    key_data: jax.Array,
    reset_key_data: jax.Array,
    states: EnvState,
    actions: jax.Array,
    autoreset: jax.Array,
    params: EnvParams,
) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, dict[str, Any]]:
    """N steps with auto-reset: NEXT_STEP restarts where ``autoreset`` (reward 0, no
    flags), SAME_STEP where this step ends. ``(held keys, states, grids, final grids,
    (N,) scalars)``; the final observation is the step's, before any restart."""
    step = jax.vmap(functools.partial(single_step, env), in_axes=(0, 0, 0, None))
    held, final, stepped, reward, terminated, truncated, info = step(
        key_data, states, actions, params
    )
    restart = (terminated | truncated) if same_step else autoreset
    held, obs, states = _restart_where(env, restart, reset_key_data, held, final, stepped, params)
    if not same_step:
        reward = jnp.where(restart, jnp.zeros_like(reward), reward)
        terminated = terminated & ~restart
        truncated = truncated & ~restart
    scalars = {
        "speed": obs.speed,
        "last_action": obs.last_action,
        "final_speed": final.speed,
        "final_last_action": final.last_action,
        "reward": reward,
        "terminated": terminated,
        "truncated": truncated,
        "restart": restart,
        "info": info,
    }
    return held, states, obs.grid, final.grid, scalars


def unpack(layout: Any, packed: np.ndarray) -> dict[str, Any]:
    """The step's scalars from their packed (N, S) float32 columns (one array for the host
    to read; exact for these flags, actions, counts and float32s) at their own dtypes."""
    leaves, treedef = jax.tree.flatten(layout)
    return jax.tree.unflatten(treedef, [packed[:, j].astype(x.dtype) for j, x in enumerate(leaves)])


class BatchFns(NamedTuple):
    reset: Any  # (key_data (N, w) uint32, params) -> (key_data, obs, states)
    reset_masked: Any  # (key_data, held, states, mask, params) -> (key_data, obs, states)
    step_next: Any  # NEXT_STEP / DISABLED :func:`_batch_step`, the scalars packed
    step_same: Any  # SAME_STEP
    render: Any  # (states, params) -> (N, H, W, 3) uint8
    layout: Any  # the step's scalars as ShapeDtypeStructs, for :func:`unpack`


@cached_program
def batch_fns(env: UrbanPedestrians) -> BatchFns:
    """The compiled calls of the vector env, and of the single env at batch 1."""
    reset = jax.vmap(functools.partial(single_reset, env), in_axes=(0, None))

    def reset_masked(key_data, held, states, mask, params):
        obs = jax.vmap(env.observation, (0, None))(states, params)
        return _restart_where(env, mask, key_data, held, obs, states, params)

    def step(same_step: bool) -> Any:
        def packed(*args: Any) -> tuple:
            *arrays, scalars = _batch_step(env, same_step, *args)
            columns = [jnp.asarray(x, jnp.float32) for x in jax.tree.leaves(scalars)]
            return *arrays, jnp.stack(columns, axis=-1)

        return jax.jit(packed)

    keys = jax.ShapeDtypeStruct((1, *key_data_shape()), jnp.uint32)
    params = env.default_params
    states = jax.eval_shape(reset, keys, params)[2]
    one = (jax.ShapeDtypeStruct((1,), jnp.int32), jax.ShapeDtypeStruct((1,), jnp.bool_))
    layout = jax.eval_shape(
        functools.partial(_batch_step, env, False), keys, keys, states, *one, params
    )[-1]
    return BatchFns(
        reset=jax.jit(reset),
        reset_masked=jax.jit(reset_masked),
        step_next=step(False),
        step_same=step(True),
        render=jax.jit(
            jax.vmap(functools.partial(viewer.render_frame, static=env.static), in_axes=(0, None))
        ),
        layout=layout,
    )


class JaxBacked:
    """What the single and vector envs share: the JAX env of ``env_id``, its compiled calls
    (:func:`batch_fns`), the batched states (leaves (N, ...)) and their rendering."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}  # 1/dt

    def _load(self, env_id: str, render_mode: str | None, overrides: dict) -> spaces.Dict:
        """Make the JAX env (``overrides`` to :func:`drqn_jax.make`); one env's obs space."""
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode={render_mode!r} is not supported; "
                f"render modes: {self.metadata['render_modes']}"
            )
        self.env_id = env_id
        self.jax_env, self.params = make_jax_env(env_id, **overrides)
        self._device_params = jax.device_put(self.params)
        self._fns = batch_fns(self.jax_env)
        self._states: EnvState | None = None
        self.render_mode = render_mode
        return gymnasium_observation_space(self.jax_env, self.params)

    def _render(self) -> np.ndarray | None:
        """(N, 240, 480, 3) uint8 frames of :func:`drqn_jax.env.viewer.render_frame`, ``None``
        (a warning) without a render mode."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() called without a render_mode; e.g. "
                'gymnasium.make("drqn_jax/UrbanPedestrians-v0", render_mode="rgb_array")'
            )
            return None
        if self._states is None:
            raise ResetNeeded(f"Cannot call {type(self).__name__}.render before reset")
        return np.array(self._fns.render(self._states, self._device_params))


def _first(tree: Any) -> Any:
    return jax.tree.map(lambda x: x[0], tree)


class UrbanPedestriansGymEnv(JaxBacked, gymnasium.Env[dict[str, Any], Any]):
    """The urban-pedestrian env (paper §V-D); ``overrides`` go to :func:`drqn_jax.make`.
    Raises ``ResetNeeded`` itself (so no order/checker wrappers); no auto-reset."""

    def __init__(
        self, env_id: str = "UrbanPedestrians-v0", render_mode: str | None = None, **overrides: Any
    ) -> None:
        self.observation_space = self._load(env_id, render_mode, overrides)
        self.action_space = spaces.Discrete(NUM_ACTIONS)
        self._no_restart = jnp.zeros(1, bool)
        self._key_data: jax.Array | None = None  # (1, w)

    @property
    def state(self) -> EnvState | None:
        """The current JAX ``EnvState`` (``None`` before the first reset)."""
        return None if self._states is None else _first(self._states)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """``(observation, {})`` of a new episode keyed from ``np_random`` (``options`` unused)."""
        super().reset(seed=seed)
        key_data = draw_key_data(self.np_random)[None]
        self._key_data, obs, self._states = self._fns.reset(key_data, self._device_params)
        return numpy_observation(_first(jax.device_get(obs))), {}

    def step(self, action: Any) -> tuple[dict[str, Any], SupportsFloat, bool, bool, dict[str, Any]]:
        """One decision step; reward a Python float, flags Python bools."""
        action = valid_action(action, self.action_space)
        if self._states is None:
            raise ResetNeeded("Cannot call UrbanPedestriansGymEnv.step before reset")
        self._key_data, self._states, grid, _, packed = self._fns.step_next(
            self._key_data,
            self._key_data,  # no restart: the reset keys go unused
            self._states,
            np.array([action], np.int32),
            self._no_restart,
            self._device_params,
        )
        grid, packed = jax.device_get((grid, packed))
        s = _first(unpack(self._fns.layout, packed))
        obs = numpy_observation(Observation(grid[0], s["speed"], s["last_action"]))
        info = {k: bool(v) if v.dtype == np.bool_ else v for k, v in s["info"].items()}
        return obs, float(s["reward"]), bool(s["terminated"]), bool(s["truncated"]), info

    def render(self) -> np.ndarray | None:
        """(240, 480, 3) uint8 frame, or ``None`` without a render mode."""
        frames = self._render()
        return None if frames is None else frames[0]


def gymnasium_ids() -> tuple[str, ...]:
    """``drqn_jax/<id>`` for every :func:`drqn_jax.registered_envs` id."""
    return tuple(f"{NAMESPACE}/{env_id}" for env_id in registered_envs())


def register_gymnasium_envs() -> tuple[str, ...]:
    """Register (unwrapped) and return :func:`gymnasium_ids`; present ids are kept."""
    for env_id, gym_id in zip(registered_envs(), gymnasium_ids(), strict=True):
        if gym_id not in gymnasium.registry:
            gymnasium.register(
                id=gym_id,
                entry_point=f"{__name__}:UrbanPedestriansGymEnv",
                vector_entry_point="drqn_jax.interop.gymnasium_vector:UrbanPedestriansVectorEnv",
                kwargs={"env_id": env_id},
                order_enforce=False,
                disable_env_checker=True,
            )
    return gymnasium_ids()
