"""A privileged planner: the ceiling of every results table (SPEC §9), never a learner.

It sees the true state *and the simulator itself*, which no learner does. At
every step it plays the simulator forward from the current state once per
candidate action, the fastest first (``accelerate``, ``steer`` = keep speed,
``slow_down``): the candidate for one step, then ``brake`` for the remaining
``horizon_steps − 1`` steps. It takes the fastest candidate after which braking
at once still avoids every collision of the ego within the horizon (SPEC §5: a
hit while it moves; the planner counts one while it rolls at all, so it never
creeps into a pedestrian below the stopped speed), and brakes when none does.
It never drives faster than its speed cap: above ``v_cap + speed_band`` the
fastest candidate is ``slow_down``, within ``± speed_band`` it is ``steer``, as
the rule-based agent tracks its ``v_max`` (SPEC §6).

The forward model is the deterministic part of the env's step
(:meth:`~drqn_jax.env.urban.UrbanPedestrians.advance`: the ego's PID and
plant, the pedestrians' walk — toward the car as the world says — and the
collision test); the random part, pedestrians replaced far away, is left out:
new ones appear at least ``spawn_min`` metres ahead, on a sidewalk. The
candidates' rollouts are one ``vmap`` of a ``lax.scan``, so the planner is one
branch-free program under ``jit`` and ``vmap`` like every agent.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import Agent, no_carry
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, STEER, EnvState
from drqn_jax.pytree import param, pytree_dataclass, validate

__all__ = ["CANDIDATES", "PlannerParams", "avoids_collision", "planner_action", "planner_agent"]

#: The candidate actions, the fastest first.
CANDIDATES = (ACCELERATE, STEER, SLOW_DOWN)


@pytree_dataclass(meta_fields=("horizon_steps",))
class PlannerParams:
    """The privileged planner's settings (SPEC §9); ``horizon_steps`` is static (a
    scan length): each value compiles its own program."""

    v_cap: float = param(
        15.0 * KMH, low=0.0, low_open=True, doc="m/s; the speed cap (at most the limit)"
    )
    speed_band: float = param(1.0 * KMH, low=0.0, doc="m/s; keep speed within ±band of v_cap")
    horizon_steps: int = param(
        20, low=1, high=100, doc="decision steps played forward per candidate (20: 2 s)"
    )

    def __post_init__(self) -> None:
        validate(self)
        # validate stores an array; a static field must stay a hashable int
        object.__setattr__(self, "horizon_steps", int(self.horizon_steps))


def avoids_collision(
    env, state: EnvState, first: jax.Array, params: EnvParams, steps: int
) -> jax.Array:
    """() bool: ``first`` for one step, then ``brake`` for ``steps − 1`` steps, and the
    ego meets no pedestrian in the collision test while it rolls (speed > 0, even
    below the stopped speed under which a hit is not its collision) in those
    ``steps`` steps before the goal ends the episode, played forward by the env's
    deterministic step."""

    def step(carry, i):
        state, hit, ended = carry
        action = jnp.where(i == 0, first, BRAKE).astype(jnp.int32)
        state, _, _, _, info = env.advance(state, action, params)
        # a hit while creeping below the stopped speed is not the ego's collision
        # (SPEC §5), but driving into a pedestrian slowly is no way to avoid one
        rolling = info["collision"] | (info["struck_while_stopped"] & (info["speed"] > 0.0))
        return (state, hit | (rolling & ~ended), ended | info["goal"]), None

    false = jnp.zeros((), bool)
    (_, hit, _), _ = jax.lax.scan(step, (state, false, false), jnp.arange(steps))
    return ~hit


def planner_action(env, state: EnvState, params: EnvParams, planner: PlannerParams) -> jax.Array:
    """() int32: the fastest candidate no faster than the cap allows after which
    braking at once avoids every collision within the horizon; ``brake`` if none."""
    v = state.ego.v
    fastest = jnp.where(
        v < planner.v_cap - planner.speed_band,
        0,
        jnp.where(v > planner.v_cap + planner.speed_band, 2, 1),
    )
    candidates = jnp.asarray(CANDIDATES, jnp.int32)
    safe = jax.vmap(lambda a: avoids_collision(env, state, a, params, planner.horizon_steps))(
        candidates
    )
    allowed = safe & (jnp.arange(len(CANDIDATES)) >= fastest)
    chosen = candidates[jnp.argmax(allowed)]
    return jnp.where(jnp.any(allowed), chosen, BRAKE).astype(jnp.int32)


def _act(params, key, obs, carry, state, env, env_params):
    return planner_action(env, state, env_params, params), carry


def planner_agent(params: PlannerParams | None = None) -> Agent:
    """The privileged planner behind the :class:`Agent` interface (it reads the true
    state and plays the simulator: a ceiling, not a learner's competitor)."""
    return Agent(
        params=PlannerParams() if params is None else params,
        name="planner",
        init_fn=no_carry,
        act_fn=_act,
    )
