"""The rule-based agent of paper §V-E (SPEC §6), a pure policy over the true state.

``brake`` when any pedestrian that is on the road or a crosswalk lies inside
the ego's corridor (lateral distance to the lane centre ≤ ego_width/2 +
ped_radius + ``corridor_margin``) and within ``lookahead`` metres ahead of the
front bumper; otherwise track ``v_max``: accelerate below ``v_max − band``,
steer (keep speed) within ±band, slow down above ``v_max + band``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import Agent, no_carry
from drqn_jax.env.grid import GridInputs
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.road_map import CROSSING_AREA, ROAD, lane_centre_y, semantic_class
from drqn_jax.env.state import ACCELERATE, BRAKE, SLOW_DOWN, STEER, EnvState
from drqn_jax.pytree import param, pytree_dataclass, validate

__all__ = [
    "RuleBasedParams",
    "must_brake",
    "rule_based_action",
    "rule_based_agent",
    "rule_based_labels",
]


@pytree_dataclass
class RuleBasedParams:
    """Thresholds of the rule-based agent (SPEC §6)."""

    v_max: float = param(15.0 * KMH, low=0.0, low_open=True, doc="m/s; tracked speed")
    speed_band: float = param(1.0 * KMH, low=0.0, doc="m/s; steer within ±band of v_max")
    lookahead: float = param(7.0, low=0.0, doc="m ahead of the front bumper")
    corridor_margin: float = param(0.5, low=0.0, doc="m added to half width + ped radius")

    def __post_init__(self) -> None:
        validate(self)


def must_brake(
    s: jax.Array, position: jax.Array, env_params: EnvParams, rb: RuleBasedParams, static
) -> jax.Array:
    """() bool: a pedestrian on the road or a crosswalk is in the corridor ahead.

    Args:
        s: () the ego's arc length (m); position: (P, 2) the pedestrians' centres.
    """
    cls = semantic_class(position, env_params, static)
    on_road = (cls == ROAD) | (cls == CROSSING_AREA)
    half_corridor = 0.5 * env_params.ego_width + env_params.ped_radius + rb.corridor_margin
    lateral = jnp.abs(position[:, 1] - lane_centre_y(env_params))
    ahead = position[:, 0] - (s + 0.5 * env_params.ego_length)
    in_front = (ahead >= -env_params.ped_radius) & (ahead <= rb.lookahead)
    return jnp.any(on_road & (lateral <= half_corridor) & in_front)


def _action(
    s: jax.Array, v: jax.Array, position: jax.Array, env_params: EnvParams, rb, static
) -> jax.Array:
    track = jnp.where(
        v < rb.v_max - rb.speed_band,
        ACCELERATE,
        jnp.where(v > rb.v_max + rb.speed_band, SLOW_DOWN, STEER),
    )
    brake = must_brake(s, position, env_params, rb, static)
    return jnp.where(brake, BRAKE, track).astype(jnp.int32)


def rule_based_action(
    state: EnvState, env_params: EnvParams, rb: RuleBasedParams, static
) -> jax.Array:
    """() int32 action of the rule-based agent for one environment."""
    ego = state.ego
    return _action(ego.s, ego.v, state.pedestrians.position, env_params, rb, static)


def rule_based_labels(
    records: GridInputs, env_params: EnvParams, rb: RuleBasedParams, static
) -> jax.Array:
    """The rule-based agent's action for each of ``records`` (any leading shape
    (…,), int32): what it would have done in the replay's stored states, which
    hold every pedestrian's position (visible or not) as the true state does."""
    lead = records.s.shape
    flat = jax.tree.map(lambda x: x.reshape((-1, *x.shape[len(lead) :])), records)
    actions = jax.vmap(_action, (0, 0, 0, None, None, None))(
        flat.s, flat.v, flat.position, env_params, rb, static
    )
    return actions.reshape(lead)


def _act(params, key, obs, carry, state, env, env_params):
    return rule_based_action(state, env_params, params, env.static), carry


def rule_based_agent(params: RuleBasedParams | None = None) -> Agent:
    """The paper's rule-based baseline behind the :class:`Agent` interface."""
    return Agent(
        params=RuleBasedParams() if params is None else params,
        name="rule-based",
        init_fn=no_carry,
        act_fn=_act,
    )
