"""Environment throughput: env steps per second, full observation, vs parallel envs.

Usage::

    python -m benchmarks.env_throughput [--batch-sizes 1 64 4096] [--steps 200] [--out DIR]
    drqn-jax bench env_throughput …

For every batch size N the whole rollout is ONE jitted program: ``lax.scan`` over T
steps of ``jax.vmap(env.step)`` on N ``UrbanPedestrians-v0`` envs with uniformly random
actions drawn inside the program. The carry ``(obs, state, key)`` is returned, so the
(45, 30, 4) float32 grid is computed every step (summing rewards alone would let XLA
drop it); ``EnvParams`` is a traced argument. Compile time (lower + compile) is apart
from run time. After one warm-up call, ``--repeats`` timed calls follow, each
continuing the episodes from the last (the carry is donated); ``--stat`` picks the
median (default) or the best. A step includes same-step auto-reset.
"""

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp

import drqn_jax
from benchmarks.harness import base_parser, compile_timed, report, time_calls

ENV_ID = "UrbanPedestrians-v0"
DEFAULT_BATCH_SIZES = (1, 16, 256, 1024, 4096, 16384, 65536)
#: The ``--quick`` rollout of peers and the bench command's test: one size, so they
#: share one compiled rollout and one init program.
QUICK_ENVS, QUICK_STEPS = 64, 10

Carry = tuple[Any, Any, jax.Array]  # (obs, state, key), every leaf with a leading batch axis


def grid_bytes(env: drqn_jax.UrbanPedestrians) -> int:
    """Bytes of one float32 observation grid (45 * 30 * 4 * 4 = 21,600 by default)."""
    rows, cols, channels = env.static.grid_shape
    return rows * cols * channels * 4


def make_init(
    env: drqn_jax.UrbanPedestrians, num_envs: int
) -> Callable[[jax.Array, drqn_jax.EnvParams], Carry]:
    """A jitted ``(key, params) -> (obs, state, key)`` resetting ``num_envs`` envs."""

    def init(key: jax.Array, params: drqn_jax.EnvParams) -> Carry:
        key, reset_key = jax.random.split(key)
        obs, state = jax.vmap(env.reset, (0, None))(jax.random.split(reset_key, num_envs), params)
        return obs, state, key

    return jax.jit(init)


def make_rollout(
    env: drqn_jax.UrbanPedestrians, num_envs: int, num_steps: int
) -> Callable[[Carry, drqn_jax.EnvParams], Carry]:
    """``(carry, params) -> carry``: ``num_steps`` vmapped steps with random actions.

    Not jitted here; the caller lowers and compiles it.
    """
    vmapped_step = jax.vmap(env.step, (0, 0, 0, None))

    def rollout(carry: Carry, params: drqn_jax.EnvParams) -> Carry:
        def body(carry: Carry, _: None) -> tuple[Carry, None]:
            _, state, key = carry
            key, action_key, step_key = jax.random.split(key, 3)
            actions = jax.random.randint(
                action_key, (num_envs,), 0, env.num_actions, dtype=jnp.int32
            )
            step_keys = jax.random.split(step_key, num_envs)
            obs, state, _, _, _, _ = vmapped_step(step_keys, state, actions, params)
            return (obs, state, key), None

        carry, _ = jax.lax.scan(body, carry, None, length=num_steps)
        return carry

    return rollout


def time_rollout(
    env: drqn_jax.UrbanPedestrians,
    params: drqn_jax.EnvParams,
    num_envs: int,
    num_steps: int,
    repeats: int,
    key: jax.Array,
    stat: str = "median",
    warmup_steps: int = 0,
) -> tuple[dict[str, Any], Carry, jax.stages.Compiled]:
    """Reset ``num_envs`` envs from ``key``, compile the rollout, run ``warmup_steps``
    untimed steps (rounded up to whole calls), then time it with ``time_calls``.

    Returns the timing row (compile apart, env steps/s), the final carry and the
    compiled rollout; ``peers`` times our env through this function too.
    """
    carry = jax.block_until_ready(make_init(env, num_envs)(key, params))
    compiled, lower_s, xla_s = compile_timed(
        jax.jit(make_rollout(env, num_envs, num_steps), donate_argnums=0), carry, params
    )
    for _ in range(-(-warmup_steps // num_steps)):
        carry = compiled(carry, params)
    carry, timing = time_calls(lambda c: compiled(c, params), carry, repeats, stat)
    env_steps = num_envs * num_steps
    steps_per_s = env_steps / timing["run_s"]
    row = {
        "batch_size": num_envs,
        "steps": num_steps,
        "env_steps_per_call": env_steps,
        "lower_s": lower_s,
        "xla_compile_s": xla_s,
        "compile_s": lower_s + xla_s,
        **timing,
        "env_steps_per_s": steps_per_s,
    }
    return row, carry, compiled


def bench_batch(
    env: drqn_jax.UrbanPedestrians,
    params: drqn_jax.EnvParams,
    num_envs: int,
    num_steps: int,
    repeats: int,
    stat: str,
    seed: int,
) -> dict[str, Any]:
    """Compile and time one batch size; return its row."""
    row, carry, _ = time_rollout(
        env, params, num_envs, num_steps, repeats, jax.random.key(seed), stat
    )
    # Sanity: the grid is finite and the episodes are alive.
    obs, _, _ = carry
    steps_per_s = row["env_steps_per_s"]
    return {
        **row,
        "us_per_env_step": 1e6 / steps_per_s,
        "grid_gb_per_s": steps_per_s * grid_bytes(env) / 1e9,
        "grid_finite": bool(jnp.all(jnp.isfinite(obs.grid))),
        "mean_occupied_cells": float(jnp.mean(jnp.sum(obs.grid[..., 0], axis=(-2, -1)))),
    }


def table_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The Markdown results table."""
    lines = [
        "| batch size | compile s | run s | env steps/s | µs per env-step |",
        "|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['batch_size']} | {r['compile_s']:.2f} | {r['run_s']:.4f} "
            f"| {r['env_steps_per_s']:,.0f} | {r['us_per_env_step']:.3f} |"
        )
    return lines


def summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The best throughput, its batch size and its compile time."""
    best = max(rows, key=lambda r: r["env_steps_per_s"])
    return {
        "best_env_steps_per_s": best["env_steps_per_s"],
        "best_batch_size": best["batch_size"],
        "compile_s_at_best": best["compile_s"],
        "grid_gb_per_s_at_best": best["grid_gb_per_s"],
    }


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = base_parser("env_throughput", __doc__)
    parser.add_argument(
        "--batch-sizes",
        type=int,
        nargs="+",
        default=list(DEFAULT_BATCH_SIZES),
        metavar="N",
        help="numbers of parallel envs (default: %(default)s)",
    )
    parser.add_argument(
        "--steps", type=int, default=200, metavar="T", help="scan length (default: 200)"
    )
    parser.add_argument(
        "--stat",
        choices=("best", "median"),
        default="median",
        help="which repeat the table reports (default: median)",
    )
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default: 0)")
    parser.add_argument(
        "--quick", action="store_true", help="batch sizes 2 and 16, 5 steps: a smoke check"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.batch_sizes, args.steps, args.repeats = [2, 16], 5, 2
    if args.steps < 1 or args.repeats < 1 or any(n < 1 for n in args.batch_sizes):
        parser.error("--batch-sizes, --steps and --repeats must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    env, params = drqn_jax.make(ENV_ID)
    rows = []
    for n in args.batch_sizes:
        row = bench_batch(env, params, n, args.steps, args.repeats, args.stat, args.seed)
        rows.append(row)
        print(
            f"[batch {n}: compile {row['compile_s']:.2f} s, run {row['run_s']:.4f} s, "
            f"{row['env_steps_per_s']:,.0f} env steps/s, cores used per timed call "
            f"{', '.join(f'{c:.2f}' for c in row['cores_used_per_call'])}]",
            file=sys.stderr,
            flush=True,
        )
        if not row["grid_finite"]:
            print(f"warning: non-finite grid values at batch {n}", file=sys.stderr)
    summ = summary(rows)
    lines = [
        f"{args.steps} steps per call (one jitted lax.scan of vmapped env.step, random "
        f"actions, obs in the carry); run s = {args.stat} of {args.repeats} timed calls "
        "after 1 warm-up; compile s = lower + compile.",
        "",
        *table_lines(rows),
        "",
        f"- best: {summ['best_env_steps_per_s']:,.0f} env steps/s at batch size "
        f"{summ['best_batch_size']} (compile {summ['compile_s_at_best']:.2f} s; float32 grid "
        f"written at {summ['grid_gb_per_s_at_best']:.2f} GB/s, {grid_bytes(env):,} B per step)",
    ]
    config = {k: getattr(args, k) for k in ("batch_sizes", "steps", "repeats", "stat", "seed")}
    result = {"env_id": ENV_ID, "config": config, "rows": rows, "summary": summ}
    title = f"{ENV_ID} env throughput (full observation)"
    return report("env_throughput", title, result, lines, args.out, argv)


if __name__ == "__main__":
    main()
