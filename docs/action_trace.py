"""Where a trained agent departs from the rule-based agent, step by step (the notebook §9).

Plays a run directory's greedy agent and the rule-based agent (SPEC §6) on the
same episodes and splits every step by what the rule-based agent would do in
that state: where it brakes (a pedestrian on the road in its corridor) and
where it drives on. Prints the share of each action there, the speed where
it drives on, and the collisions: whether the car was stopped, where the
pedestrian met it (its front, side or rear) and what the pedestrian was
doing (docs/notebook/yielding-world.md §10: among heedless pedestrians, who walk into cars)::

    python docs/action_trace.py runs/reproduce --episodes 64
"""

from __future__ import annotations

import argparse
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import drqn_jax
from drqn_jax.agents import Agent, drqn_agent, rule_based_agent
from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_action
from drqn_jax.env.collision import box_disc_overlap, ego_box
from drqn_jax.env.state import BRAKE
from drqn_jax.experiments.runner import load_run, load_trained_network

ACTIONS = ("accelerate", "slow_down", "brake", "steer")
BEHAVIOURS = ("crossing", "jaywalking", "sidewalk")  # SPEC §3, state.CROSSING … SIDEWALK
SIDES = ("front", "side", "rear")
SPEED_LIMIT_KMH = 15.0  # v_ref (SPEC §2)


def collider(state: Any, params: Any) -> tuple[jax.Array, jax.Array]:
    """Where the pedestrian that overlaps the ego met it (0 front: ahead of the
    front bumper, 1 side, 2 rear) and its behaviour; the first such pedestrian."""
    centre, half = ego_box(state.ego.s, params)
    peds = state.pedestrians
    hit = jnp.argmax(box_disc_overlap(centre, half, peds.position, params.ped_radius))
    dx = peds.position[hit, 0] - state.ego.s
    side = jnp.where(dx > half[0], 0, jnp.where(dx < -half[0], 2, 1))
    return side, peds.behaviour[hit]


def trace(agent: Agent, key: jax.Array, env: Any, params: Any) -> dict[str, jax.Array]:
    """One episode's per-step (max_steps,) action, rule-based label, speed (m/s),
    live flag, collision flag, and where the collision happened (:func:`collider`)."""
    k_reset, k_carry, k_run = jax.random.split(key, 3)
    obs, state = env.reset_env(k_reset, params)
    carry = agent.init_carry(k_carry)

    def step(loop, k):
        obs, state, carry, done = loop
        k_act, k_env = jax.random.split(k)
        label = rule_based_action(state, params, RuleBasedParams(), env.static)
        action, carry = agent.act(k_act, obs, carry, state, env, params)
        speed = state.ego.v
        obs, state, _, terminated, truncated, info = env.step_env(k_env, state, action, params)
        side, behaviour = collider(state, params)
        out = {
            "action": action,
            "label": label,
            "speed": speed,
            "live": ~done,
            "collision": info["collision"] & ~done,
            "side": side,
            "behaviour": behaviour,
        }
        return (obs, state, carry, done | terminated | truncated), out

    keys = jax.random.split(k_run, env.static.max_steps)
    _, out = jax.lax.scan(step, (obs, state, carry, jnp.zeros((), bool)), keys)
    return out


def report(name: str, out: dict[str, np.ndarray]) -> None:
    live = out["live"]
    must = live & (out["label"] == BRAKE)
    free = live & (out["label"] != BRAKE)
    print(f"{name}: {int(out['collision'].sum())} collisions, {int(live.sum())} steps")
    for where, mask in (("where it brakes", must), ("where it drives on", free)):
        shares = np.bincount(out["action"][mask], minlength=4) / max(int(mask.sum()), 1)
        text = ", ".join(f"{a} {100 * s:.0f} %" for a, s in zip(ACTIONS, shares, strict=True))
        print(f"  {where} ({100 * mask.sum() / live.sum():.0f} % of steps): {text}")
    kmh = out["speed"][free] * 3.6
    stopped = 100 * (kmh < 1).mean()
    print(f"  speed where it drives on: {kmh.mean():.1f} km/h; stopped in {stopped:.0f} %")
    live_kmh = out["speed"][live] * 3.6
    above = live_kmh[live_kmh > SPEED_LIMIT_KMH]
    share = 100 * above.size / live_kmh.size
    text = f"  above the {SPEED_LIMIT_KMH:.0f} km/h limit (fined) in {share:.0f} % of steps"
    if above.size:
        text += f", at {above.mean():.2f} km/h on average, {above.max():.2f} at most"
    print(text)
    hits = out["collision"]
    if hits.any():
        n = int(hits.sum())
        stopped = 100 * (out["speed"][hits] * 3.6 < 1).mean()

        def shares(names: tuple[str, ...], codes: np.ndarray) -> str:
            counts = np.bincount(codes, minlength=len(names))
            return ", ".join(f"{m} {100 * c / n:.0f} %" for m, c in zip(names, counts, strict=True))

        print(f"  collisions: the car stopped (< 1 km/h) in {stopped:.0f} %")
        print(f"    where the pedestrian met it: {shares(SIDES, out['side'][hits])}")
        print(f"    what it was doing: {shares(BEHAVIOURS, out['behaviour'][hits])}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", help="a drqn-jax train run directory")
    parser.add_argument("--episodes", type=int, default=64)
    parser.add_argument("--seed", type=int, default=123, help="key of the episodes")
    args = parser.parse_args(argv)
    config = load_run(args.run_dir)
    network, params, _ = load_trained_network(config, args.run_dir)
    env, env_params = config.make_env()
    keys = drqn_jax.evaluation.episode_keys(jax.random.key(args.seed), args.episodes)
    for name, agent in (("drqn", drqn_agent(network, params)), ("rule-based", rule_based_agent())):
        out = jax.jit(jax.vmap(lambda k, agent=agent: trace(agent, k, env, env_params)))(keys)
        report(name, jax.tree.map(np.asarray, out))


if __name__ == "__main__":
    main()
