"""Hand-built scenes for the env's and the agents' tests (SPEC §1–6).

Every scene is a full ``EnvState`` with the default P pedestrians: the ones a
test is about come first, the rest stand still on the far (left) sidewalk
ahead of the ego, where they are never despawned, never done and never in
the ego's corridor. Closed-loop scenes run one jitted ``lax.scan`` of
``env.step_env`` (:func:`run_scene`: one compile per process for every test
file that uses it) whose action is either a fixed action or the rule-based
agent's.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_action
from drqn_jax.env.ego import initial_ego
from drqn_jax.env.state import (
    ACCELERATE,
    CROSSING,
    NUM_WAYPOINTS,
    EgoState,
    EnvState,
    PedestrianState,
)

SCAN_STEPS = 200  # one fixed length: one compile serves every closed-loop scene
LANE_Y = -1.75
FAR_X = 1000.0  # x of pedestrians that must stay outside the grid window
_PED_FIELDS = {f.name for f in dataclasses.fields(PedestrianState)}


@partial(jax.jit, static_argnums=0)
def _scan_steps(env, state, key, fixed_action, use_rule, params):
    """``SCAN_STEPS`` steps of ``env.step_env``; action fixed or rule-based."""
    rb = RuleBasedParams()

    def body(st, k):
        rule = rule_based_action(st, params, rb, env.static)
        action = jnp.where(use_rule, rule, fixed_action).astype(jnp.int32)
        _, nxt, r, term, trunc, info = env.step_env(k, st, action, params)
        out = {
            "action": action,
            "v": nxt.ego.v,
            "s": nxt.ego.s,
            "ped_position": nxt.pedestrians.position,
            "waypoint_index": nxt.pedestrians.waypoint_index,
            "collision": info["collision"],
            "struck_while_stopped": info["struck_while_stopped"],
            "terminated": term,
            "truncated": trunc,
            "reward": r,
            "ttc": info["ttc"],
        }
        return nxt, out

    return jax.lax.scan(body, state, jax.random.split(key, SCAN_STEPS))


def run_scene(env, state, params, *, action=ACCELERATE, rule=False, seed=0):
    """``SCAN_STEPS`` steps of ``env.step_env`` from ``state``: the final state and the
    per-step record (NumPy leaves: action, v, s, ped_position, waypoint_index,
    collision, struck_while_stopped, terminated, truncated, reward, ttc)."""
    final, out = _scan_steps(
        env, state, jax.random.key(seed), jnp.int32(action), jnp.asarray(rule), params
    )
    return final, jax.tree.map(np.asarray, out)


def make_ego(params, static, *, s: float = 5.0, v: float = 0.0) -> EgoState:
    """Ego at arc length ``s`` and speed ``v`` (setpoint v, no acceleration)."""
    return initial_ego(params, static).replace(
        s=jnp.float32(s), v=jnp.float32(v), v_setpoint=jnp.float32(v)
    )


def make_peds(
    static,
    positions,
    *,
    targets=None,
    speeds=None,
    velocities=None,
    headings=None,
    park_x: float = 40.0,
    park_y: float = 5.0,
) -> PedestrianState:
    """P pedestrians: the given ones first, the rest standing on the left sidewalk.

    A pedestrian with speed 0 stands still forever (its target differs from its
    position, so it never "arrives" and is never replaced as done). Parked
    pedestrians stand at ``x = park_x + i``, ``y = park_y``.
    """
    num = static.num_pedestrians
    n = len(positions)
    assert n <= num
    pos = np.zeros((num, 2), np.float32)
    pos[:n] = np.asarray(positions, np.float32).reshape(n, 2)
    pos[n:, 0] = park_x + np.arange(num - n)
    pos[n:, 1] = park_y
    tgt = pos + np.array([0.0, 5.0], np.float32)  # standing: a target it never walks to
    if targets is not None:
        tgt[:n] = np.asarray(targets, np.float32).reshape(n, 2)
    spd = np.zeros(num, np.float32)
    if speeds is not None:
        spd[:n] = speeds
    vel = np.zeros((num, 2), np.float32)
    if velocities is not None:
        vel[:n] = np.asarray(velocities, np.float32).reshape(n, 2)
    head = np.arctan2(tgt[:, 1] - pos[:, 1], tgt[:, 0] - pos[:, 0]).astype(np.float32)
    if headings is not None:
        head[:n] = headings
    fields = {
        "position": jnp.asarray(pos),
        "velocity": jnp.asarray(vel),
        "heading": jnp.asarray(head),
        "desired_speed": jnp.asarray(spd),
        "behaviour": jnp.full((num,), CROSSING, jnp.int32),
        "waypoints": jnp.asarray(np.repeat(tgt[:, None, :], NUM_WAYPOINTS, axis=1)),
        "waypoint_index": jnp.zeros((num,), jnp.int32),
        "waited": jnp.zeros((num,), jnp.float32),
        "visible": jnp.ones((num,), bool),
    }
    if "speed" in _PED_FIELDS:  # the norm of the velocity, stored where the step knows it
        fields["speed"] = jnp.asarray(np.linalg.norm(vel, axis=-1).astype(np.float32))
    return PedestrianState(**fields)


def make_state(ego: EgoState, peds: PedestrianState) -> EnvState:
    return EnvState(
        ego=ego,
        pedestrians=peds,
        last_action=jnp.int32(-1),
        time=jnp.int32(0),
    )


def box_distance(px, py, s, params, inflate: float = 0.0):
    """Euclidean distance (float64) from points to the ego box at ``s`` (0 inside)."""
    half_x = 0.5 * params.ego_length + inflate
    half_y = 0.5 * params.ego_width + inflate
    dx = np.maximum(np.abs(np.asarray(px, np.float64) - s) - half_x, 0.0)
    dy = np.maximum(np.abs(np.asarray(py, np.float64) - LANE_Y) - half_y, 0.0)
    return np.hypot(dx, dy)


def first_index(mask) -> int:
    hits = np.flatnonzero(np.asarray(mask))
    assert hits.size > 0, "condition never reached"
    return int(hits[0])


@partial(jax.jit, static_argnums=0)
def _scan_agent(env, state, key, agent, params):
    """``SCAN_STEPS`` steps of ``env.step_env`` from ``state``, ``agent`` acting."""

    def body(loop, k):
        st, carry = loop
        key_act, key_env = jax.random.split(k)
        action, carry = agent.act(key_act, env.observation(st, params), carry, st, env, params)
        _, nxt, _, _, _, info = env.step_env(key_env, st, action, params)
        out = {"action": action, "v": nxt.ego.v, "s": nxt.ego.s, "collision": info["collision"]}
        return (nxt, carry), out

    init = (state, agent.init_carry(key))
    (final, _), out = jax.lax.scan(body, init, jax.random.split(key, SCAN_STEPS))
    return final, out


def run_agent_scene(env, state, params, agent, *, seed=0):
    """``SCAN_STEPS`` steps of ``env.step_env`` from ``state`` with ``agent`` (any
    :class:`~drqn_jax.agents.Agent`) acting: the final state and the per-step record
    (NumPy leaves: action, v, s, collision)."""
    final, out = _scan_agent(env, state, jax.random.key(seed), agent, params)
    return final, jax.tree.map(np.asarray, out)
