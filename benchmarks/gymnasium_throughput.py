"""Gymnasium clients: steps/s of the single env and of the native vector env.

Usage::

    python -m benchmarks.gymnasium_throughput [--num-envs 256] [--steps 200] [--out DIR]
    drqn-jax bench gymnasium_throughput …

What a Gymnasium user gets: ``gym.make("drqn_jax/UrbanPedestrians-v0")``
stepped from Python with random actions (NumPy observations out, one jitted
call per step), and ``gym.make_vec(…, num_envs=N)`` (``UrbanPedestriansVectorEnv``:
one jitted call per step for all N envs, auto-reset included), each against the
bare ``jit(vmap(step_env))`` of the JAX env at the same N (device arrays in and out,
no host transfer, no reset at all: episodes run on past their end): the ceiling a
Python-side client can approach. Run s = median of ``--repeats`` timed loops of ``--steps`` steps
after a warm-up loop. Targets: the single env ≥ 5,000 steps/s; the
vector env ≥ 50 % of ``jit(vmap(step_env))``'s env steps/s at 256 envs.
"""

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np

import drqn_jax
from benchmarks.harness import base_parser, markdown_table, report, time_calls

ENV_ID = "UrbanPedestrians-v0"
GYM_ID = f"drqn_jax/{ENV_ID}"


def _loop(step: Any, actions: np.ndarray) -> Any:
    """A call for :func:`time_calls`: ``len(actions)`` steps of ``step``."""

    def call(carry: Any) -> Any:
        for a in actions:
            carry = step(carry, a)
        return carry

    return call


def bench_single(steps: int, repeats: int, seed: int) -> dict[str, Any]:
    env = gym.make(GYM_ID)
    env.reset(seed=seed)
    actions = np.random.default_rng(seed).integers(0, 4, size=steps)

    def step(carry: Any, action: Any) -> Any:
        _, _, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            env.reset()
        return carry

    _, timing = time_calls(_loop(step, actions), None, repeats)
    return {
        "client": "gym.make (single env)",
        "envs": 1,
        **timing,
        "steps_per_s": steps / timing["run_s"],
    }


def bench_vector(num_envs: int, steps: int, repeats: int, seed: int) -> dict[str, Any]:
    env = gym.make_vec(GYM_ID, num_envs=num_envs)
    env.reset(seed=seed)
    actions = np.random.default_rng(seed).integers(0, 4, size=(steps, num_envs))

    def step(carry: Any, action: Any) -> Any:
        env.step(action)
        return carry

    _, timing = time_calls(_loop(step, actions), None, repeats)
    rate = num_envs * steps / timing["run_s"]
    return {"client": "gym.make_vec", "envs": num_envs, **timing, "steps_per_s": rate}


def bench_jax(num_envs: int, steps: int, repeats: int, seed: int) -> dict[str, Any]:
    env, params = drqn_jax.make(ENV_ID)
    keys = jax.random.split(jax.random.key(seed), num_envs)
    _, states = jax.vmap(env.reset, (0, None))(keys, params)
    step = jax.jit(jax.vmap(env.step_env, (0, 0, 0, None)))
    actions = jnp.asarray(np.random.default_rng(seed).integers(0, 4, size=(steps, num_envs)))

    def one(carry: Any, action: Any) -> Any:
        key, states = carry
        key, sub = jax.random.split(key)
        _, states, *_ = step(jax.random.split(sub, num_envs), states, action, params)
        return key, states

    _, timing = time_calls(_loop(one, actions), (jax.random.key(seed + 1), states), repeats)
    rate = num_envs * steps / timing["run_s"]
    return {
        "client": "jit(vmap(env.step_env)) (JAX, no host, no reset)",
        "envs": num_envs,
        **timing,
        "steps_per_s": rate,
    }


COLUMNS = {
    "client": "client",
    "envs": "envs",
    "run_s": "run s",
    "steps_per_s": "env steps/s",
}


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("gymnasium_throughput", __doc__)
    parser.add_argument("--num-envs", type=int, default=256, help="vector envs (default 256)")
    parser.add_argument("--steps", type=int, default=200, help="steps per timed loop (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    parser.add_argument("--quick", action="store_true", help="4 envs, 10 steps, 2 repeats")
    args = parser.parse_args(argv)
    if args.quick:
        args.num_envs, args.steps, args.repeats = 4, 10, 2
    if args.num_envs < 1 or args.steps < 1:
        parser.error("--num-envs and --steps: must be >= 1")
    single = bench_single(args.steps, args.repeats, args.seed)
    vector = bench_vector(args.num_envs, args.steps, args.repeats, args.seed)
    ceiling = bench_jax(args.num_envs, args.steps, args.repeats, args.seed)
    share = vector["steps_per_s"] / ceiling["steps_per_s"]
    lines = [
        f"Random actions; run s = median of {args.repeats} loops of {args.steps} steps after "
        "a warm-up loop (compiling included in the warm-up).",
        "",
        *markdown_table([single, vector, ceiling], COLUMNS),
        "",
        f"- single env: {single['steps_per_s']:,.0f} steps/s (target >= 5,000: "
        f"{'met' if single['steps_per_s'] >= 5000 else 'not met'})",
        f"- vector env at {args.num_envs} envs: {100 * share:.0f} % of jit(vmap(step_env)) "
        f"(target >= 50 % at 256 envs: {'met' if share >= 0.5 else 'not met'})",
    ]
    result = {"config": vars(args), "rows": [single, vector, ceiling], "vector_share": share}
    return report("gymnasium_throughput", "Gymnasium clients", result, lines, args.out, argv)


if __name__ == "__main__":
    main()
