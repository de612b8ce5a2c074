"""A privileged planner, the ceiling of every results table (SPEC §9): on the true state it
plays the env's step forward (each candidate once, then ``brake``) and takes the fastest
after which braking avoids every collision within the horizon, under its speed cap."""

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import Agent, no_carry
from drqn_jax.agents.rule_based import track_speed
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, STEER, EnvState
from drqn_jax.pytree import param, pytree_dataclass, validate

#: The candidate actions, the fastest first.
CANDIDATES = (ACCELERATE, STEER, SLOW_DOWN)


@pytree_dataclass(meta_fields=("horizon_steps",))
class PlannerParams:
    """The planner's settings (SPEC §9); ``horizon_steps`` is static (a scan length)."""

    v_cap: float = param(15.0 * KMH, low=0.0, low_open=True, doc="m/s; the speed cap")
    speed_band: float = param(1.0 * KMH, low=0.0, doc="m/s; keep speed within ±band of v_cap")
    horizon_steps: int = param(20, low=1, high=100, doc="steps played per candidate (2 s)")

    def __post_init__(self) -> None:
        validate(self)
        # validate stores an array; a static field must stay a hashable int
        object.__setattr__(self, "horizon_steps", int(self.horizon_steps))


def avoids_collision(
    env, state: EnvState, first: jax.Array, params: EnvParams, steps: int
) -> jax.Array:
    """() bool: after ``first`` then ``brake`` for ``steps − 1`` steps the ego hits no
    pedestrian while it rolls at all (speed > 0) before the goal."""

    def step(carry, i):
        state, hit, ended = carry
        action = jnp.where(i == 0, first, BRAKE).astype(jnp.int32)
        state, _, _, _, info = env.advance(state, action, params)
        # creeping into a pedestrian below the stopped speed is no way to avoid one
        rolling = info["collision"] | (info["struck_while_stopped"] & (info["speed"] > 0.0))
        return (state, hit | (rolling & ~ended), ended | info["goal"]), None

    false = jnp.zeros((), bool)
    (_, hit, _), _ = jax.lax.scan(step, (state, false, false), jnp.arange(steps))
    return ~hit


def planner_action(env, state: EnvState, params: EnvParams, planner: PlannerParams) -> jax.Array:
    """() int32: the fastest safe candidate the cap allows; ``brake`` if none."""
    candidates = jnp.asarray(CANDIDATES, jnp.int32)
    # the fastest the cap allows: the candidate that holds v within v_cap ± speed_band
    fastest = jnp.argmax(candidates == track_speed(state.ego.v, planner.v_cap, planner.speed_band))
    safe = jax.vmap(lambda a: avoids_collision(env, state, a, params, planner.horizon_steps))(
        candidates
    )
    allowed = safe & (jnp.arange(len(CANDIDATES)) >= fastest)
    chosen = candidates[jnp.argmax(allowed)]
    return jnp.where(jnp.any(allowed), chosen, BRAKE).astype(jnp.int32)


def _act(params, key, obs, carry, state, env, env_params):
    return planner_action(env, state, env_params, params), carry


def planner_agent(params: PlannerParams | None = None) -> Agent:
    """The privileged planner as an :class:`Agent`."""
    params = PlannerParams() if params is None else params
    return Agent(params=params, name="planner", init_fn=no_carry, act_fn=_act, every_tick=True)
