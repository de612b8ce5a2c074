"""Training throughput: env steps/s and gradient updates/s of learning, every learner.

Usage::

    python -m benchmarks.train_throughput [--learners default pqn ppo] [--envs N ...]
        [--seeds S ...] [--iterations 20] [--rollouts 1] [--set SECTION.FIELD=VALUE]
        [--repeats 3] [--out DIR] [--quick]

Each config's own trainer is timed by :func:`drqn_jax.commands.bench.train_figures`
once learning runs (the program ``drqn-jax train`` compiles for its chunks; with
``--seeds`` S > 1, S seeds ``jax.vmap``-ed in one program, as a sweep's ``vmap``
strategy trains them). The env steps and gradient updates of a call are counted from
the training state, so every learner is measured in what it does: the replay DRQN over
``--iterations`` iterations (one step of each of its envs and its updates) at its own
number of envs, an on-policy learner (PQN, PPO) over ``--rollouts`` rollouts and their
update epochs at each of ``--envs`` (its own by default). ``--set`` overrides every
learner's config (e.g. ``--set network.recurrent=64``). A figure is the best of
``--repeats`` calls after the warm-up; compile time (lower + compile) is apart.

``--quick`` runs each learner's algorithm on ``smoke``'s tiny world and network: a
smoke check of the script, not a measurement.
"""

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

from benchmarks.harness import base_parser, markdown_table, report
from drqn_jax.commands.bench import train_figures
from drqn_jax.config import Config, load_config
from drqn_jax.learners.hyperparams import ON_POLICY

#: ``--quick``: each learner's algorithm on ``smoke``'s tiny world and network.
QUICK_LEARNER = {
    "dqn": [],
    "ppo": ["train.rollout_steps=8", "train.num_minibatches=1"],
    "pqn": ["train.rollout_steps=8", "train.num_minibatches=1", "network.layer_norm=true"],
}

LEARNER_COLUMNS = {
    "learner": "config",
    "algorithm": "learner",
    "num_envs": "envs per seed",
    "seeds": "seeds (vmap)",
    "env_steps_per_s": "env steps/s of learning (all seeds)",
    "grad_steps_per_s": "gradient updates/s",
    "compile_s": "compile s",
}


def learner_config(
    name: str, overrides: Sequence[str], envs: int | None, calls: int, quick: bool
) -> Config:
    """``name`` with ``overrides`` (``quick``: its algorithm on ``smoke``); an on-policy
    learner at ``envs`` envs (None: its own) with a step budget that outlasts ``calls``
    rollouts. The replay DRQN keeps its own envs and budget."""
    config = load_config(name, overrides)
    if quick:
        algorithm = config["train"]["algorithm"]
        extra = [f"train.algorithm={algorithm}", *QUICK_LEARNER[algorithm]]
        name, overrides = "smoke", [*extra, *overrides]
        config = load_config(name, overrides)
    train = config["train"]
    if train["algorithm"] not in ON_POLICY:
        return config
    envs = train["num_envs"] if envs is None else envs
    steps = calls * train["rollout_steps"] * envs
    sized = [f"train.num_envs={envs}", f"train.num_env_steps={steps}"]
    sized += [f"train.num_episodes={max(train['num_episodes'], steps // 10)}"]
    return load_config(name, [*overrides, *sized])


def learner_rows(args: argparse.Namespace) -> list[dict[str, Any]]:
    """One row per learner × envs × seeds: :func:`train_figures` in rates."""
    rows = []
    for name in args.learners:
        on_policy = load_config(name, args.set)["train"]["algorithm"] in ON_POLICY
        iterations = args.rollouts if on_policy else args.iterations
        for envs in (args.envs or [None]) if on_policy else [None]:
            for seeds in args.seeds:
                config = learner_config(name, args.set, envs, 6 * iterations, args.quick)
                figures = train_figures(config, iterations, seeds, repeats=args.repeats)
                if isinstance(figures, str):
                    raise SystemExit(f"{name} at {envs} envs: {figures}")
                seconds = figures["seconds"]
                rows.append(
                    {
                        "learner": name,
                        "algorithm": config["train"]["algorithm"],
                        **figures,
                        "env_steps_per_s": figures["env_steps"] / seconds,
                        "grad_steps_per_s": figures["grad_steps"] / seconds,
                        "overrides": args.set,
                    }
                )
                print(rows[-1], file=sys.stderr, flush=True)
    return rows


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = base_parser("train_throughput", __doc__)
    parser.set_defaults(repeats=3)
    parser.add_argument(
        "--learners",
        nargs="+",
        default=["default", "pqn", "ppo"],
        metavar="CONFIG",
        help="the configs whose learners are timed (default: default pqn ppo)",
    )
    parser.add_argument("--envs", type=int, nargs="+", metavar="N", help="on-policy envs per seed")
    parser.add_argument(
        "--seeds", type=int, nargs="+", default=[1], metavar="S", help="vmapped seeds (default 1)"
    )
    parser.add_argument(
        "--iterations", type=int, default=20, metavar="I", help="replay DRQN: per call (20)"
    )
    parser.add_argument(
        "--rollouts", type=int, default=1, metavar="R", help="on-policy: per call (default 1)"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="override every learner's config",
    )
    parser.add_argument(
        "--quick", action="store_true", help="tiny network and sizes: a smoke check only"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.iterations, args.repeats = 5, 1
    values = (args.iterations, args.repeats, args.rollouts, *args.seeds, *(args.envs or ()))
    if min(values) < 1:
        parser.error("--iterations, --repeats, --rollouts, --seeds and --envs must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    start = time.perf_counter()
    rows = learner_rows(args)
    fastest = max(rows, key=lambda r: r["env_steps_per_s"])
    lines = [
        f"Env steps per second of learning (best of {args.repeats} calls once learning runs; "
        "env steps and gradient updates counted from the training state). Replay DRQN: "
        f"{args.iterations} iterations per call; PQN and PPO: {args.rollouts} "
        "rollout(s) and their update epochs per call."
        + (f" Overrides: {' '.join(args.set)}." if args.set else ""),
        "",
        *markdown_table(rows, LEARNER_COLUMNS),
        "",
        f"Fastest: `{fastest['learner']}` ({fastest['algorithm']}) at {fastest['num_envs']} "
        f"envs × {fastest['seeds']} seed(s).",
    ]
    result = {"rows": rows, "wall_s": time.perf_counter() - start, "quick": args.quick}
    title = "Learning throughput of every learner" + (" (QUICK: tiny sizes)" if args.quick else "")
    return report("train_throughput", title, result, lines, args.out, argv)


if __name__ == "__main__":
    main()
