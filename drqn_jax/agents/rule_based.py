"""The rule-based agent of paper §V-E (SPEC §6) on the true state: ``brake`` for a pedestrian
on the road in the ego's corridor within ``lookahead``, else track ``v_max``; ``horizon`` > 0
(not the paper's) also brakes for one walking into that corridor within ``horizon`` s."""

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import Agent, no_carry
from drqn_jax.env.grid import CORRIDOR_MARGIN, GridInputs, corridor_times, times_between
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.road_map import CROSSING_AREA, ROAD, semantic_class
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, STEER, EnvState
from drqn_jax.pytree import param, pytree_dataclass, validate


@pytree_dataclass
class RuleBasedParams:
    """Thresholds of the rule-based agent (SPEC §6)."""

    v_max: float = param(15.0 * KMH, low=0.0, low_open=True, doc="m/s; tracked speed")
    speed_band: float = param(1.0 * KMH, low=0.0, doc="m/s; steer within ±band of v_max")
    lookahead: float = param(7.0, low=0.0, doc="m ahead of the front bumper")
    corridor_margin: float = param(CORRIDOR_MARGIN, low=0.0, doc="m added to half width + radius")
    horizon: float = param(0.0, low=0.0, doc="s; brake for one entering within it (0: paper)")

    def __post_init__(self) -> None:
        validate(self)


def must_brake(g: GridInputs, env_params: EnvParams, rb: RuleBasedParams, static) -> jax.Array:
    """() bool: a pedestrian (``g.position``, ``g.velocity`` (P, 2)) on the road is in the
    corridor ahead of the ego (``g.s``, ``g.v`` ()), or walks into it within ``rb.horizon``."""
    cls = semantic_class(g.position, env_params, static)
    on_road = (cls == ROAD) | (cls == CROSSING_AREA)
    ahead, in_lane, start, end = corridor_times(g, env_params, rb.corridor_margin)
    in_front = (ahead >= -env_params.ped_radius) & (ahead <= rb.lookahead)
    now = jnp.any(on_road & in_lane & in_front)
    # in the corridor within [0, horizon], and within the look-ahead then
    near = times_between(ahead, g.velocity[:, 0], -jnp.inf, rb.lookahead)
    start = jnp.maximum(jnp.maximum(start, near[0]), 0.0)
    end = jnp.minimum(jnp.minimum(end, near[1]), rb.horizon)
    soon = jnp.any(start <= end)
    return now | ((rb.horizon > 0.0) & soon)


def track_speed(v: jax.Array, target: jax.Array, band: jax.Array) -> jax.Array:
    """() int32 action keeping ``v`` within ``target ± band``: accelerate, slow_down or steer."""
    return jnp.where(
        v < target - band, ACCELERATE, jnp.where(v > target + band, SLOW_DOWN, STEER)
    ).astype(jnp.int32)


def _action(g: GridInputs, env_params: EnvParams, rb: RuleBasedParams, static) -> jax.Array:
    """() int32: ``brake`` if :func:`must_brake`, else track ``v_max`` (``g``: one record)."""
    track = track_speed(g.v, rb.v_max, rb.speed_band)
    return jnp.where(must_brake(g, env_params, rb, static), BRAKE, track).astype(jnp.int32)


def rule_based_action(
    state: EnvState, env_params: EnvParams, rb: RuleBasedParams, static
) -> jax.Array:
    """() int32 action of the rule-based agent for one environment."""
    return _action(GridInputs.of(state.ego, state.pedestrians), env_params, rb, static)


def rule_based_labels(
    records: GridInputs, env_params: EnvParams, rb: RuleBasedParams, static
) -> jax.Array:
    """(…,) int32 rule-based actions in replay records of any leading shape (they hold
    every pedestrian, visible or not, as the true state does)."""
    lead = records.s.shape
    flat = jax.tree.map(lambda x: x.reshape((-1, *x.shape[len(lead) :])), records)
    return jax.vmap(_action, (0, None, None, None))(flat, env_params, rb, static).reshape(lead)


def _act(params, key, obs, carry, state, env, env_params):
    return rule_based_action(state, env_params, params, env.static), carry


def rule_based_agent(params: RuleBasedParams | None = None) -> Agent:
    """The paper's rule-based baseline behind the :class:`Agent` interface."""
    params = RuleBasedParams() if params is None else params
    return Agent(params=params, name="rule-based", init_fn=no_carry, act_fn=_act, every_tick=True)
