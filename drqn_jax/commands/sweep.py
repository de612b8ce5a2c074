"""``drqn-jax sweep``: a sweep file's points as compiled programs, and its results."""

import argparse
import json
import time
from pathlib import Path

from drqn_jax.commands import default_run_dir, say
from drqn_jax.config import ConfigError
from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.runner import EXIT_INTERRUPTED, EXIT_OK


def cmd_sweep(args: argparse.Namespace) -> int:
    """Train and evaluate a grid of seeds x hyperparameters as one program per shape

    Points that share shapes train together in compiled jit(vmap) calls, sharded over the
    local devices, as many per call as the memory plan allows; each run is evaluated on the
    same episodes. Writes results.md and results.csv (mean, std, 95 % t-interval and IQM
    across seeds per setting), runs.json and OUT/agents/run-NNNN. Ctrl-C saves checkpoints
    (status 130); --resume continues, also a sweep file given more points (more seeds).
    With several processes each trains its slice and process 0 writes the results.
    """
    import jax

    from drqn_jax.experiments.sweep import load_sweep, summarize_sweep, sweep_csv, sweep_table
    from drqn_jax.experiments.sweep_plan import describe_plan, init_distributed, plan_calls
    from drqn_jax.experiments.sweep_runner import run_sweep

    dist = init_distributed(args.coordinator, args.num_processes, args.process_id)
    if dist.processes > 1 and args.out is None:
        raise ConfigError("several processes need --out (the same directory name on every one)")
    if args.resume and args.out is None:
        raise ConfigError("--resume needs --out DIR, the directory of the sweep to continue")
    if args.memory_gb is not None and not args.memory_gb > 0:
        raise ConfigError(f"--memory-gb = {args.memory_gb}: must be > 0")
    sweep = load_sweep(args.sweep_file, args.overrides)
    devices = len(jax.local_devices())
    budget = None if args.memory_gb is None else int(args.memory_gb * 1e9)
    calls = plan_calls(sweep, devices, dist, budget, "--memory-gb", args.strategy)
    if dist.leader:
        say(sweep.describe())
    say(describe_plan(calls, devices, dist))
    if args.dry_run:
        return EXIT_OK
    out = Path(args.out or default_run_dir("sweep", args.sweep_file))
    start = time.perf_counter()
    outcome = run_sweep(
        sweep,
        out,
        calls=calls,
        dist=dist,
        resume=args.resume,
        quiet=args.quiet,
        keep_agents=not args.no_agents,
    )
    if outcome.status == "interrupted":
        say(
            f"interrupted; checkpoints saved, continue with: drqn-jax sweep {args.sweep_file} "
            f"--out {out} --resume (and the same --set options)"
        )
        return EXIT_INTERRUPTED
    if not dist.leader:
        return EXIT_OK
    rows = summarize_sweep(outcome.results)
    table = sweep_table(rows)
    atomic_write_text(out / "results.md", table + "\n")
    atomic_write_text(out / "results.csv", sweep_csv(rows))
    atomic_write_text(out / "runs.json", json.dumps(outcome.results, indent=2) + "\n")
    print(table)
    elapsed = time.perf_counter() - start
    print(f"\n{len(outcome.results)} runs in {elapsed:.1f} s; results in {out}")
    return EXIT_OK
