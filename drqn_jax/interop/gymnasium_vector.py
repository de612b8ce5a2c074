"""Gymnasium vector env over the JAX simulator (SPEC §1–5), one jitted vmapped call per
step; sub-env ``i`` behaves exactly like ``gymnasium.make(id)`` reset with ``seed + i``."""

from typing import Any

import jax
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from drqn_jax.env.state import NUM_ACTIONS, EnvState, Observation
from drqn_jax.interop.gymnasium_env import (
    JaxBacked,
    draw_key_data,
    key_data_shape,
    numpy_observation,
    unpack,
    valid_action,
)


def _batched_info(values: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, np.ndarray]:
    """Gymnasium's vector info layout: ``key`` (N,), zero where ``mask`` is not, and ``_key``."""
    if not mask.any():
        return {}
    out: dict[str, np.ndarray] = {}
    for name, value in values.items():
        value = np.asarray(value)
        out[name] = np.where(mask, value, np.zeros_like(value))
        out[f"_{name}"] = mask.copy()
    return out


class UrbanPedestriansVectorEnv(JaxBacked, VectorEnv[dict[str, Any], Any, np.ndarray]):
    """``num_envs`` envs in one jitted call; ``autoreset_mode`` NEXT_STEP, SAME_STEP (as
    ``SyncVectorEnv``) or DISABLED (``reset(options={"reset_mask": mask})``)."""

    def __init__(
        self,
        num_envs: int = 1,
        env_id: str = "UrbanPedestrians-v0",
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs = {num_envs!r}: must be an integer >= 1")
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        self.num_envs = num_envs
        self.single_observation_space = self._load(env_id, render_mode, overrides)
        self.metadata = {**JaxBacked.metadata, "autoreset_mode": self.autoreset_mode}
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.single_action_space = spaces.Discrete(NUM_ACTIONS)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * num_envs
        self._seeds: list[int | None] = [None] * num_envs
        self._next_key_data = np.zeros((num_envs, *key_data_shape()), np.uint32)  # next reset keys
        self._key_data: jax.Array | None = None  # (N, w) held keys
        self._ended = np.zeros(num_envs, bool)  # NEXT_STEP: reset on the next step

    @property
    def np_random(self) -> tuple[np.random.Generator | None, ...]:
        """The sub-environments' generators."""
        return tuple(self._rngs)

    @property
    def np_random_seed(self) -> tuple[int | None, ...]:
        """The seeds the sub-environments' generators were last made from."""
        return tuple(self._seeds)

    @property
    def states(self) -> EnvState | None:
        """The batched JAX ``EnvState`` (leading axis N; ``None`` before reset)."""
        return self._states

    def _take_reset_keys(self, seeds: list[int | None], which: np.ndarray) -> np.ndarray:
        """(N, w) uint32 reset keys for ``which``, as the single env would draw them."""
        keys = np.zeros_like(self._next_key_data)
        following = self._next_key_data.copy()
        for i in np.flatnonzero(which):
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i], self._seeds[i] = seeding.np_random(seeds[i])
                following[i] = draw_key_data(self._rngs[i])
            keys[i] = following[i]
            following[i] = draw_key_data(self._rngs[i])
        self._next_key_data = following
        return keys

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Reset all or ``options["reset_mask"]``; ``seed``: None, s (env i: s + i) or N seeds."""
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int | np.integer):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(
                    f"seed: a list of length num_envs={self.num_envs} was expected, "
                    f"got length {len(seeds)}"
                )
        mask = None if options is None else options.get("reset_mask")
        if mask is not None:
            if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_:
                raise TypeError(f"options['reset_mask'] must be a NumPy bool array, got {mask!r}")
            if mask.shape != (self.num_envs,) or not mask.any():
                raise ValueError(
                    f"options['reset_mask'] must have shape ({self.num_envs},) and at least one "
                    f"True value, got {mask!r}"
                )
            if self._states is None:
                raise ResetNeeded("the first reset must reset every sub-environment")
        which = np.ones(self.num_envs, bool) if mask is None else mask
        key_data = self._take_reset_keys(seeds, which)
        if mask is None:
            self._key_data, obs, self._states = self._fns.reset(key_data, self._device_params)
        else:
            self._key_data, obs, self._states = self._fns.reset_masked(
                key_data, self._key_data, self._states, mask, self._device_params
            )
        self._ended = self._ended & ~which
        return numpy_observation(jax.device_get(obs)), {}

    def step(
        self, actions: Any
    ) -> tuple[dict[str, Any], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every sub-environment (infos in Gymnasium's vector layout)."""
        actions = valid_action(actions, self.action_space)
        if self._states is None:
            raise ResetNeeded("Cannot call UrbanPedestriansVectorEnv.step before reset")
        same_step = self.autoreset_mode == AutoresetMode.SAME_STEP
        autoreset = self._ended & (self.autoreset_mode == AutoresetMode.NEXT_STEP)
        if self.autoreset_mode == AutoresetMode.DISABLED and self._ended.any():
            raise ResetNeeded(
                f"sub-environments {np.flatnonzero(self._ended).tolist()} ended; with "
                "AutoresetMode.DISABLED reset them with reset(options={'reset_mask': mask})"
            )
        step = self._fns.step_same if same_step else self._fns.step_next
        self._key_data, self._states, grid, final_grid, packed = step(
            self._key_data,
            self._next_key_data,
            self._states,
            np.asarray(actions, np.int32),
            autoreset,
            self._device_params,
        )
        s = unpack(self._fns.layout, jax.device_get(packed))
        observations = numpy_observation(
            Observation(jax.device_get(grid), s["speed"], s["last_action"])
        )
        terminated, truncated, info = s["terminated"], s["truncated"], s["info"]
        done = terminated | truncated
        if same_step:
            infos = _batched_info(info, ~done)
            if done.any():
                final_obs_data = Observation(
                    jax.device_get(final_grid), s["final_speed"], s["final_last_action"]
                )
                final = numpy_observation(final_obs_data)
                final_obs = np.full(self.num_envs, None, dtype=object)
                for i in np.flatnonzero(done):
                    final_obs[i] = {name: value[i] for name, value in final.items()}
                infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
                infos["final_info"], infos["_final_info"] = _batched_info(info, done), done.copy()
        else:
            infos = _batched_info(info, ~autoreset)
        restarted = s["restart"]
        if restarted.any():
            self._take_reset_keys([None] * self.num_envs, restarted)
        self._ended = done
        return observations, np.asarray(s["reward"], np.float64), terminated, truncated, infos

    def render(self) -> tuple[np.ndarray, ...] | None:
        """N (240, 480, 3) uint8 frames for ``"rgb_array"``."""
        frames = self._render()
        return None if frames is None else tuple(frames)
