"""``UrbanPedestrians`` (SPEC §1–5) in the gymnax contract: the env holds only its hashable
:class:`StaticEnvParams`; ``reset(key, params)``, ``step(key, state, action, params) -> (obs,
state, reward, terminated, truncated, info)`` with same-step auto-reset (``step_env`` without)."""

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.env import spaces
from drqn_jax.env.collision import classify_hits, time_to_collision
from drqn_jax.env.collision import reward as compute_reward
from drqn_jax.env.ego import ego_step, initial_ego
from drqn_jax.env.grid import GRID_HIGH, GRID_LOW, rasterize_grid
from drqn_jax.env.params import EnvParams, StaticEnvParams, check_compatible
from drqn_jax.env.pedestrians import (
    despawn_mask,
    occlusion_mask,
    respawn_pedestrians,
    spawn_pedestrians,
    step_pedestrians,
)
from drqn_jax.env.state import NO_ACTION, NUM_ACTIONS, EnvState, Observation
from drqn_jax.pytree import tree_where


def _opaque(params: EnvParams) -> EnvParams:
    """Hide ``params`` from constant folding: closed over, XLA would rewrite ``x / v_ref``
    as ``x * (1 / v_ref)`` and round differently from params passed as arguments."""
    return jax.lax.optimization_barrier(params)


StepResult = tuple[Observation, EnvState, jax.Array, jax.Array, jax.Array, dict[str, Any]]


@dataclasses.dataclass(frozen=True)
class UrbanPedestrians:
    """Urban road with unsignalized intersections and pedestrians (paper §V-D)."""

    static: StaticEnvParams = dataclasses.field(default_factory=StaticEnvParams)

    @property
    def name(self) -> str:
        return "UrbanPedestrians-v0"

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    @property
    def default_params(self) -> EnvParams:
        return EnvParams()

    def check_params(self, params: EnvParams) -> EnvParams:
        """Cross-check ``params`` against this env's static settings; return them."""
        if not isinstance(params, EnvParams):
            raise TypeError(f"params must be an EnvParams, got {type(params).__name__}")
        check_compatible(self.static, params)
        return params

    def observation(self, state: EnvState, params: EnvParams) -> Observation:
        """The agent's observation of ``state`` (SPEC §4)."""
        params = _opaque(params)
        grid = rasterize_grid(state.ego, state.pedestrians, params, self.static)
        return Observation(
            grid=grid,
            speed=(state.ego.v * (1.0 / params.v_ref)).astype(jnp.float32),
            last_action=state.last_action,
        )

    def _spawn_range(self, s: jax.Array, params: EnvParams, initial: jax.Array):
        """x range of new pedestrians: around the start at reset, ahead of the ego otherwise."""
        lo = jnp.where(initial, params.spawn_initial_min, params.spawn_min)
        hi = jnp.where(initial, params.spawn_initial_max, params.spawn_max)
        return s + lo, s + hi

    def reset_state(self, key: jax.Array, params: EnvParams) -> EnvState:
        """A fresh episode: ego at rest at the start, P pedestrians around it."""
        params = _opaque(params)
        ego = initial_ego(params, self.static)
        lo, hi = self._spawn_range(ego.s, params, jnp.asarray(True))
        peds = spawn_pedestrians(key, lo, hi, params, self.static)
        return EnvState(
            ego=ego,
            pedestrians=peds.replace(visible=occlusion_mask(key, params, self.static)),
            last_action=jnp.asarray(NO_ACTION, jnp.int32),
            time=jnp.zeros((), jnp.int32),
        )

    def reset_env(self, key: jax.Array, params: EnvParams) -> tuple[Observation, EnvState]:
        state = self.reset_state(key, params)
        return self.observation(state, params), state

    def reset(
        self, key: jax.Array, params: EnvParams | None = None
    ) -> tuple[Observation, EnvState]:
        """``(obs, state)`` of a new episode."""
        params = self.default_params if params is None else params
        return self.reset_env(key, params)

    def advance(
        self, state: EnvState, action: jax.Array, params: EnvParams, hold: jax.Array | None = None
    ) -> tuple[EnvState, jax.Array, jax.Array, jax.Array, dict[str, jax.Array]]:
        """The deterministic part of one tick (all but replacing pedestrians, SPEC §2–5):
        ``(stepped state, reward, terminated, truncated, info)``; ``hold``: see
        :func:`~drqn_jax.env.ego.ego_step`. An action outside 0 … 3 is clipped and flagged
        ``info["invalid_action"]``; a non-integer dtype is a TypeError."""
        params = _opaque(params)
        action = jnp.asarray(action)
        if not jnp.issubdtype(action.dtype, jnp.integer):
            raise TypeError(
                f"action: dtype {action.dtype} is not an integer; actions are 0 … "
                f"{NUM_ACTIONS - 1} (accelerate, slow_down, brake, steer)"
            )
        unclipped = action.astype(jnp.int32)
        action = jnp.clip(unclipped, 0, NUM_ACTIONS - 1)
        invalid = action != unclipped
        ego = ego_step(state.ego, action, params, hold)
        peds = step_pedestrians(state.pedestrians, ego, params)
        collided, struck = classify_hits(ego, peds, params)
        ttc = time_to_collision(ego, peds, params, self.static)
        r = compute_reward(collided, ttc, ego.v, params)
        goal = ego.s >= params.goal_x
        time = state.time + 1
        terminated = collided | goal
        truncated = (time >= self.static.max_steps) & ~terminated
        stepped = EnvState(ego=ego, pedestrians=peds, last_action=action, time=time)
        info = {
            "collision": collided,
            "struck_while_stopped": struck,
            "goal": goal,
            "ttc": ttc,
            "distance": ego.s - params.ego_start_s,
            "speed": ego.v,
            "time": time,
            "invalid_action": invalid,
        }
        return stepped, r, terminated, truncated, info

    def _next_state(
        self, key: jax.Array, stepped: EnvState, params: EnvParams, reset: jax.Array
    ) -> EnvState:
        """Finish a step: replace far or finished pedestrians and draw the occlusion; with
        ``reset`` (() bool) restart exactly as ``reset_state(key, …)`` does."""
        params = _opaque(params)
        ego = tree_where(reset, initial_ego(params, self.static), stepped.ego)
        gone = reset | despawn_mask(stepped.pedestrians, stepped.ego, params)
        lo, hi = self._spawn_range(ego.s, params, reset)
        peds = respawn_pedestrians(key, stepped.pedestrians, gone, lo, hi, params, self.static)
        peds = peds.replace(visible=occlusion_mask(key, params, self.static))
        return EnvState(
            ego=ego,
            pedestrians=peds,
            last_action=jnp.where(reset, NO_ACTION, stepped.last_action).astype(jnp.int32),
            time=jnp.where(reset, 0, stepped.time).astype(jnp.int32),
        )

    def _tick(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams, hold=None
    ) -> tuple[EnvState, jax.Array, jax.Array, jax.Array, dict[str, jax.Array]]:
        """One tick of ``dt`` without auto-reset: ``advance`` and the new pedestrians."""
        stepped, r, terminated, truncated, info = self.advance(state, action, params, hold)
        next_state = self._next_state(key, stepped, params, jnp.asarray(False))
        return next_state, r, terminated, truncated, info

    def decide(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams
    ) -> tuple[EnvState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """``action`` held for k = ``decision_steps`` ticks, no auto-reset (SPEC §2): ``(state,
        summed reward, terminated, truncated, info)``, no tick after a collision or the goal;
        tick keys ``split(key, k)``; ``info``: the last tick's, events over all played ticks,
        ``ttc`` their least, ``info["ticks"]`` every tick's (leaves (k,), ``played``)."""
        k = self.static.decision_steps
        if k == 1:
            return self._tick(key, state, action, params)

        def tick(carry, xs):
            state, total, terminated, truncated, info = carry
            key_tick, later = xs
            ticked, r, term, trunc, now = self._tick(key_tick, state, action, params, later)
            live = ~(terminated | truncated)  # no tick has ended the episode yet
            merged = tree_where(live, now, info)
            for flag in ("collision", "goal", "struck_while_stopped"):
                merged[flag] = info[flag] | (live & now[flag])
            merged["ttc"] = jnp.where(live, jnp.minimum(info["ttc"], now["ttc"]), info["ttc"])
            carry = (
                tree_where(live, ticked, state),
                total + jnp.where(live, r, 0.0),
                terminated | (live & term),
                truncated | (live & trunc),
                merged,
            )
            return carry, dict(now, played=live)

        _, r0, _, _, info0 = jax.eval_shape(self.advance, state, action, params)
        info = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), info0)
        info["ttc"] = jnp.full((), jnp.inf, jnp.float32)
        false = jnp.zeros((), bool)
        init = (state, jnp.zeros(r0.shape, r0.dtype), false, false, info)
        xs = (jax.random.split(key, k), jnp.arange(k) > 0)
        (state, reward, terminated, truncated, info), ticks = jax.lax.scan(tick, init, xs)
        return state, reward, terminated, truncated, dict(info, ticks=ticks)

    def step_env(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams
    ) -> StepResult:
        """One decision without auto-reset (:meth:`decide`): ``(obs, state, reward,
        terminated, truncated, info)``."""
        next_state, r, terminated, truncated, info = self.decide(key, state, action, params)
        return self.observation(next_state, params), next_state, r, terminated, truncated, info

    def step(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams | None = None
    ) -> StepResult:
        """``step_env(key, …)``, or where the episode ends ``reset(key, params)``'s state and
        observation, with ``step_env``'s in ``info["final_state"]`` and
        ``info["final_observation"]`` (computed only when the caller uses them)."""
        params = _opaque(self.default_params if params is None else params)
        if self.static.decision_steps == 1:
            stepped, r, terminated, truncated, info = self.advance(state, action, params)
            next_state = self._next_state(key, stepped, params, terminated | truncated)
            final = self._next_state(key, stepped, params, jnp.asarray(False))
        else:
            final, r, terminated, truncated, info = self.decide(key, state, action, params)
            fresh = self.reset_state(key, params)
            done = terminated | truncated
            next_state = tree_where(done, fresh, final)
        info = dict(info, final_state=final, final_observation=self.observation(final, params))
        return self.observation(next_state, params), next_state, r, terminated, truncated, info

    def action_space(self, params: EnvParams | None = None) -> spaces.Discrete:
        """``Discrete(4)``: accelerate, slow_down, brake, steer."""
        return spaces.Discrete(NUM_ACTIONS)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Dict:
        """``Dict(grid, speed, last_action)`` with the documented bounds (SPEC §4)."""
        params = self.default_params if params is None else params
        v_max = params.max_vehicle_speed / params.v_ref
        return spaces.Dict(
            {
                "grid": spaces.Box(
                    np.array(GRID_LOW, np.float32),
                    np.array(GRID_HIGH, np.float32),
                    self.static.grid_shape,
                    jnp.float32,
                ),
                "speed": spaces.Box(0.0, v_max, (), jnp.float32),
                "last_action": spaces.Discrete(NUM_ACTIONS + 1, start=NO_ACTION),
            }
        )
