"""``drqn-jax bench``: the suite of ``benchmarks/`` in a child process, or quick figures."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from drqn_jax.config import ConfigError, load_config
from drqn_jax.experiments.runner import EXIT_OK

#: The suite's benchmarks, in the order ``drqn-jax bench all`` runs them.
SUITE = ("env_throughput", "peers", "train_throughput", "evaluation", "gymnasium_throughput")

#: Benchmarks run by name only, not by ``all`` (long, not throughput figures).
TOOLS = ("gymnax_validation", "learning_curve", "decision_interval")


def _run_benchmark(name: str, args: Sequence[str]) -> int:
    """``python -m benchmarks.NAME ARGS`` of this package's clone in a child process."""
    root = Path(__file__).resolve().parents[2]  # the clone: drqn_jax/commands/..
    if not (root / "benchmarks" / "__init__.py").is_file():
        raise ConfigError(
            f"bench {name}: the suite lives in benchmarks/ of a clone of the repository "
            f"(not found beside {Path(__file__).parent}); install with pip install -e ."
        )
    path = os.pathsep.join(p for p in (str(root), os.environ.get("PYTHONPATH")) if p)
    command = [sys.executable, "-m", f"benchmarks.{name}", *args]
    return subprocess.run(command, env={**os.environ, "PYTHONPATH": path}).returncode


def cmd_bench(args: argparse.Namespace) -> int:
    """``quick``, ``all`` (``args.options`` from their parsers) or one benchmark by name."""
    if args.name == "quick":
        from drqn_jax.experiments.bench import bench_env, bench_train
        from drqn_jax.experiments.machine import machine_info, machine_lines

        quick = args.options
        config = load_config(quick.config, quick.overrides)
        if quick.num_envs < 1 or quick.steps < 1 or quick.iterations < 1:
            raise ConfigError("--num-envs, --steps and --iterations must be >= 1")
        print(bench_env(config, quick.num_envs, quick.steps))
        for k in quick.decision_steps or [None]:
            overrides = [*quick.overrides, f"env.decision_steps={k}"] if k else quick.overrides
            print(bench_train(load_config(quick.config, overrides), quick.iterations))
        print("\n".join(machine_lines(machine_info())))
        return EXIT_OK
    if args.name != "all":
        return _run_benchmark(args.name, args.args)
    options = args.options
    passed = ["--repeats", str(options.repeats)] if options.repeats else []
    passed += ["--out", options.out] if options.out else []
    passed += ["--quick"] if options.quick else []
    status = EXIT_OK
    for name in SUITE:
        print(f"\n# drqn-jax bench {name} {' '.join(passed)}\n", flush=True)
        status = max(status, _run_benchmark(name, passed))
    return status
