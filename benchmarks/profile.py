"""Where a compiled program's time goes, XLA op by XLA op (the profile behind issue 7's work).

Usage::

    python -m benchmarks.profile env [--num-envs 4096] [--steps 20] [--top 25] [--out DIR]
    python -m benchmarks.profile update [--updates 10] [--top 25] [--out DIR]
    drqn-jax bench profile …

* ``env``: the rollout of ``benchmarks/env_throughput.py`` (``lax.scan`` of
  ``vmap(env.step)``, random actions, the observation in the carry) on
  ``--num-envs`` envs for ``--steps`` steps;
* ``update``: ``--updates`` gradient updates of the paper preset in one
  ``lax.scan`` (``benchmarks/train_throughput.py``'s program), on a replay
  filled with ``--fill-episodes`` episodes of the untrained agent.

The program is compiled and run once, then run once more under
``jax.profiler.trace``. XLA:CPU records every op it executes (a fusion, a
library call, a ``while``); the table sums each op's time over the call and
divides by the steps (or updates), next to the op's output shape and the JAX
operation XLA names as its origin. Ops inside a ``while`` or ``cond`` are
counted both on their own and in the enclosing op, so the shares add up to
more than 1. The profiler's own overhead is a few per cent; the total is the
wall time of the traced call.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import json
import re
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax

import drqn_jax
from benchmarks.env_throughput import ENV_ID, make_init, make_rollout
from benchmarks.harness import base_parser, markdown_table, report

__all__ = ["hlo_origins", "main", "op_times", "profile_call"]

_OP_LINE = re.compile(
    r"\n\s*%([\w.\-]+) = (.+?) [a-z][\w\-]*\([^\n]*?metadata=\{op_name=\"([^\"]+)\""
)


def hlo_origins(hlo_text: str) -> dict[str, tuple[str, str]]:
    """Every named op of an optimised HLO module: its output shape and JAX origin.

    A tuple-shaped op (``while``, ``cond``) shows as ``(n-tuple)``.
    """
    origins = {}
    for name, shape, origin in _OP_LINE.findall(hlo_text):
        if shape.startswith("("):
            shape = f"({shape.count('[')}-tuple)"
        origins[name] = (shape.split("{")[0], origin)
    return origins


def op_times(trace_dir: str | Path) -> tuple[dict[str, float], dict[str, int]]:
    """Total µs and count per event name in a ``jax.profiler`` Perfetto trace."""
    path = next(Path(trace_dir).rglob("*.trace.json.gz"))
    with gzip.open(path) as fh:
        events = json.load(fh)
    events = events["traceEvents"] if isinstance(events, dict) else events
    total: dict[str, float] = collections.Counter()
    count: dict[str, int] = collections.Counter()
    for e in events:
        if e.get("ph") == "X":
            total[e["name"]] += e.get("dur", 0.0)
            count[e["name"]] += 1
    return total, count


def profile_call(compiled: jax.stages.Compiled, *args: Any) -> tuple[float, list[dict]]:
    """Run ``compiled(*args)`` once untraced, once traced; (traced wall ms, per-op rows)."""
    jax.block_until_ready(compiled(*args))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            jax.block_until_ready(compiled(*args))
        total, count = op_times(tmp)
    wall_ms = total.get("ThunkExecutor::Execute (wait for completion)", 0.0) / 1e3
    origins = hlo_origins(compiled.as_text())
    rows = [
        {
            "op": name,
            "us": us,
            "calls": count[name],
            "shape": origins[name][0],
            "origin": origins[name][1],
        }
        for name, us in total.items()
        if name in origins
    ]
    return wall_ms, sorted(rows, key=lambda r: -r["us"])


def _short_origin(op_name: str) -> str:
    """The JAX operation at the end of an XLA ``op_name`` path (``vmap()/cond`` → ``cond``)."""
    parts = [p for p in op_name.split("/")[1:] if p not in ("body", "closed_call")]
    return "/".join(parts[-2:]) if parts else op_name


def _env_program(args: argparse.Namespace) -> tuple[jax.stages.Compiled, tuple, int, str]:
    env, params = drqn_jax.make(ENV_ID)
    carry = make_init(env, args.num_envs)(jax.random.key(args.seed), params)
    rollout = jax.jit(make_rollout(env, args.num_envs, args.steps))
    compiled = rollout.lower(carry, params).compile()
    what = f"{args.num_envs} envs × {args.steps} steps of `vmap(env.step)`"
    return compiled, (carry, params), args.steps, what


def _update_program(args: argparse.Namespace) -> tuple[jax.stages.Compiled, tuple, int, str]:
    from benchmarks.train_throughput import fill_replay, make_updates, update_args
    from drqn_jax.learners import TrainConfig, make_train

    trainer = make_train(TrainConfig())
    fill_run = jax.jit(trainer.run, static_argnums=1, donate_argnums=0)
    state, _ = fill_replay(trainer, jax.random.key(args.seed), args.fill_episodes, fill_run)
    updates = jax.jit(make_updates(trainer.gradient_update, args.updates))
    call_args = update_args(trainer, state, jax.random.key(args.seed + 1))
    compiled = updates.lower(*call_args).compile()
    what = f"{args.updates} gradient updates of the paper preset in one `lax.scan`"
    return compiled, call_args, args.updates, what


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = base_parser("profile", __doc__)
    parser.add_argument("program", choices=("env", "update"))
    parser.add_argument("--num-envs", type=int, default=4096, help="env: envs (4096)")
    parser.add_argument("--steps", type=int, default=20, help="env: steps per call (20)")
    parser.add_argument("--updates", type=int, default=10, help="update: updates per call (10)")
    parser.add_argument(
        "--fill-episodes", type=int, default=4, help="update: episodes in the replay (4)"
    )
    parser.add_argument("--top", type=int, default=25, help="ops in the table (25)")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    build = _env_program if args.program == "env" else _update_program
    compiled, call_args, per, what = build(args)
    wall_ms, rows = profile_call(compiled, *call_args)
    unit = "step" if args.program == "env" else "update"
    for r in rows:
        r[f"ms_per_{unit}"] = r["us"] / 1e3 / per
        r["share"] = r["us"] / 1e3 / wall_ms
        r["origin_short"] = _short_origin(r["origin"])
    lines = [
        f"{what}: {wall_ms / per:.2f} ms per {unit} under the profiler "
        f"({wall_ms:.1f} ms for the call). The {args.top} costliest XLA ops:",
        "",
        *markdown_table(
            rows[: args.top],
            {
                "op": "XLA op",
                f"ms_per_{unit}": f"ms per {unit}",
                "share": "share",
                "calls": "runs per call",
                "shape": "output",
                "origin_short": "from (JAX op)",
            },
        ),
    ]
    result = {"program": args.program, "what": what, "wall_ms": wall_ms, "per": per, "ops": rows}
    return report("profile", f"Profile: {args.program}", result, lines, args.out, argv)


if __name__ == "__main__":
    main(sys.argv[1:])
