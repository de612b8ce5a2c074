"""The ``drqn-jax`` command line (it only parses; :mod:`drqn_jax.commands` runs). Exit
statuses: 0 done; 1 the run failed (non-finite loss; last good checkpoint kept); 2 a
configuration, usage or checkpoint problem; 130 interrupted (after a checkpoint)."""

import argparse
import inspect
import shlex
import sys
from collections.abc import Callable, Sequence

from drqn_jax import __version__
from drqn_jax.agents.shipped import shipped_agents
from drqn_jax.commands.bench import SUITE, TOOLS, cmd_bench
from drqn_jax.commands.runs import cmd_evaluate, cmd_export, cmd_replay, cmd_reproduce, cmd_train
from drqn_jax.commands.study import cmd_frontier, cmd_report, cmd_study
from drqn_jax.commands.sweep import cmd_sweep
from drqn_jax.config import ConfigError, config_names
from drqn_jax.experiments.checkpoint import CheckpointError
from drqn_jax.experiments.frontier import PLANNER_CAPS_KMH
from drqn_jax.experiments.runner import EXIT_INTERRUPTED, EXIT_USAGE
from drqn_jax.experiments.sweep import STRATEGIES

Parser = argparse.ArgumentParser


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Help with each option's default, unless the text names it or it says nothing."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        silent = action.default in (None, False, [], argparse.SUPPRESS)
        if "(default:" in text or silent or not action.option_strings:
            return text
        return text + " (default: %(default)s)"


def _flags(parser: Parser, flags: dict[str, str]) -> None:
    """``store_true`` options: name -> help."""
    for name, help_text in flags.items():
        parser.add_argument(name, action="store_true", help=help_text)


def _set_option(parser: Parser, help_text: str) -> None:
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help=help_text,
    )


def _config_options(parser: Parser) -> None:
    names = ", ".join(config_names())
    parser.add_argument(
        "--config", default="default", help=f"TOML file, or a name in configs/ ({names})"
    )
    _set_option(parser, "override one field (repeatable), e.g. --set train.learning_rate=3e-4")


def _run_dir_options(parser: Parser, prefix: str) -> None:
    """``--run-dir``, and ``--rrd`` for the training curves."""
    parser.add_argument(
        "--run-dir", help=f"where to write the run (default: runs/{prefix}-<config>-<UTC time>)"
    )
    parser.add_argument(
        "--rrd",
        metavar="PATH",
        help="also write the training curves (return, length, loss, ε, collision rate per "
        "episode) as a rerun recording to PATH when training stops",
    )


def _agent_options(parser: Parser, verb: str) -> None:
    """``[RUN_DIR]`` and ``--agent``: a trained run's DRQN or a built-in agent."""
    parser.add_argument(
        "run_dir",
        nargs="?",
        help="a run directory (its DRQN agent), or a sweep's trained agent: OUT/agents/run-NNNN",
    )
    shipped = shipped_agents()
    parser.add_argument(
        "--agent",
        choices=("drqn", "rule-based", "planner", "random", "accelerate", *shipped),
        help=f"agent to {verb}; drqn: the run's trained agent, whatever its learner; planner: "
        "the privileged planner, which sees the true state and plays the simulator forward "
        "(a ceiling, not a learner; [planner] of the config)"
        + (f"; {', '.join(shipped)}: a trained agent shipped with drqn_jax " if shipped else " ")
        + "(default: drqn with RUN_DIR, rule-based without)",
    )


def _episodes_options(parser: Parser, default: int | None = None) -> None:
    """``--episodes`` and ``--seed``: which evaluation episodes."""
    text = "episodes (default: evaluate.episodes)" if default is None else "episodes to record"
    parser.add_argument("--episodes", type=int, default=default, help=text)
    parser.add_argument("--seed", type=int, help="run.seed for the evaluation key")


def _train_options(train: Parser) -> None:
    _config_options(train)
    _run_dir_options(train, "train")
    train.add_argument(
        "--resume",
        metavar="RUN_DIR",
        help="continue the run in RUN_DIR from its last checkpoint (uses its config.toml)",
    )


def _evaluate_options(ev: Parser) -> None:
    _agent_options(ev, "evaluate")
    _episodes_options(ev)
    ev.add_argument("--json", metavar="PATH", help="write the metrics as JSON ('-': stdout)")
    _config_options(ev)


def _reproduce_options(rep: Parser) -> None:
    rep.add_argument(
        "--train",
        action="store_true",
        help="train the agent again first (the shipped agent's config, or --config), "
        "with an estimate of how long on this device",
    )
    rep.add_argument(
        "--config",
        help="with --train: a TOML file or a name in configs/ to train instead of the "
        "shipped agent's config",
    )
    _set_option(rep, "override one field (repeatable), e.g. --set evaluate.episodes=100")
    _run_dir_options(rep, "reproduce")


def _export_options(export: Parser) -> None:
    export.add_argument(
        "run_dir", help="a finished run directory (drqn-jax train) or a sweep's OUT/agents/run-NNNN"
    )
    export.add_argument("out", help="the directory to write")
    export.add_argument(
        "--command",
        required=True,
        dest="training_command",
        metavar="TEXT",
        help="the command that trained the run, kept in OUT/provenance.json",
    )


def _replay_options(replay: Parser) -> None:
    _agent_options(replay, "record")
    _episodes_options(replay, default=5)
    replay.add_argument(
        "--out",
        metavar="PATH",
        help="the .rrd file to write (default: RUN_DIR/episodes.rrd, or episodes.rrd "
        "without RUN_DIR)",
    )
    _config_options(replay)


def _sweep_options(sweep: Parser) -> None:
    sweep.add_argument("sweep_file", help="the sweep TOML (base config, [set], [axes])")
    _set_option(sweep, "override one field of every point (repeatable)")
    sweep.add_argument("--out", help="results directory (default: runs/sweep-<file>-<time>)")
    _flags(
        sweep,
        {
            "--dry-run": "validate, plan and describe; run nothing",
            "--resume": "continue the sweep in --out from its checkpoints",
            "--no-agents": "do not keep the trained agents in OUT/agents (about 4 MB each, "
            "paper network)",
        },
    )
    sweep.add_argument(
        "--strategy",
        choices=STRATEGIES,
        help="how a device trains its runs: batched (vmap) or one after another (map); "
        "default: the sweep file's, else auto (map on CPU, vmap elsewhere)",
    )
    sweep.add_argument(
        "--memory-gb",
        type=float,
        help="memory one call may use (default: the host's MemAvailable, or the devices' own)",
    )
    group = sweep.add_argument_group(
        "several processes (machines)",
        "give all three, or set JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID",
    )
    group.add_argument("--coordinator", metavar="HOST:PORT", help="process 0's address")
    group.add_argument("--num-processes", type=int, metavar="N", help="processes in all")
    group.add_argument("--process-id", type=int, metavar="I", help="this process (0 … N-1)")


def _study_options(study: Parser) -> None:
    study.add_argument(
        "--configs",
        default="paper,default,dqn",
        help="comma-separated config names in configs/ or TOML paths (one row each)",
    )
    study.add_argument("--seeds", type=int, default=5, help="seeds 0 … N-1 per config")
    study.add_argument("--episodes", type=int, default=1000, help="evaluation episodes per run")
    _set_option(study, "override one field of every config (repeatable)")
    study.add_argument(
        "--eval-envs",
        default="",
        metavar="ENV_ID,...",
        help="also evaluate every config's trained agents among these envs' pedestrians, "
        "on the same episodes (one more row each, beside that env's rule-based agent)",
    )
    study.add_argument("--out", help="study directory (runs/study-<configs>)")
    study.add_argument("--smooth", type=int, default=10, help="running mean of the curves")
    _flags(
        study,
        {
            "--no-png": "skip curves.png and safety_speed.png",
            "--dry-run": "validate and describe the study; run nothing",
            "--estimate": "time one training chunk of every config on this device and print "
            "the study's training wall time; train nothing",
            "--report-only": "train nothing: the table and curves of the runs that have "
            "finished so far",
        },
    )
    study.add_argument(
        "--results",
        metavar="PATH",
        help="also store the table's rows, this command and its wall time as section "
        "--section of this results file (e.g. docs/results.json; other sections stay)",
    )
    study.add_argument("--section", help="the section of --results (default: OUT's name)")
    study.add_argument(
        "--runs-store",
        metavar="PATH",
        help="keep an interrupted study's finished runs here, for the same command in a "
        "fresh --out; removed once it finishes (default with --results: "
        "finished-runs/SECTION.json beside the results file)",
    )


def _frontier_options(frontier: Parser) -> None:
    _config_options(frontier)
    _episodes_options(frontier)
    _flags(
        frontier,
        {
            "--wide": "sweep the wide grid (drqn_jax.experiments.frontier.WIDE_GRID, the "
            "evidence behind the default settings; about 25 min on 2 cores at 1000 episodes)",
        },
    )
    frontier.add_argument(
        "--caps",
        default=",".join(f"{c:g}" for c in PLANNER_CAPS_KMH),
        metavar="KMH,...",
        help="the planner's speed caps (km/h, at most the speed limit)",
    )
    _flags(frontier, {"--no-planner": "the rule-based sweep only"})
    frontier.add_argument(
        "--check",
        type=int,
        default=0,
        metavar="N",
        help="also evaluate N random rule-based settings (a reviewer's) and say how many lie "
        "above the frontier (stored as the section's comparison)",
    )
    frontier.add_argument("--out", help="where to write frontier.json/.png")
    frontier.add_argument(
        "--results",
        metavar="PATH",
        help="also store both frontiers as section --section of this results file",
    )
    frontier.add_argument("--section", default="frontier", help="the section of --results")
    _flags(frontier, {"--no-png": "skip frontier.png"})


def _report_options(report: Parser) -> None:
    report.add_argument("documents", nargs="+", help="Markdown files with results blocks")
    report.add_argument("--results", default="docs/results.json", help="the results file")
    _flags(
        report,
        {"--check": "change nothing: exit 1 if a document's blocks differ from the results file"},
    )


def _bench_options(bench: Parser) -> None:
    bench.add_argument(
        "name",
        nargs="?",
        default="all",
        choices=("all", "quick", *SUITE, *TOOLS),
        help="a benchmark of the suite, 'all' of them, or 'quick' (figures of one config)",
    )
    bench.add_argument(
        "args",
        nargs=argparse.REMAINDER,
        help="the benchmark's own options (drqn-jax bench NAME --help lists them)",
    )


def _bench(args: argparse.Namespace) -> int:
    """Run the benchmark suite (or one of its benchmarks) on this machine

    Run the benchmark suite of benchmarks/ (a clone of the repository is needed): each
    benchmark prints a Markdown table with the machine it ran on, and --out DIR writes
    DIR/NAME.json and DIR/NAME.md. 'all' runs every benchmark of the suite with the options
    --repeats, --out and --quick passed on to each. 'quick' prints env steps/s and training
    throughput of one config and needs no clone.
    """
    # the options of quick and all are parsed here, a benchmark's own by the benchmark
    parser = Parser(prog=f"drqn-jax bench {args.name}", formatter_class=_Formatter)
    if args.name == "quick":
        parser.add_argument("--num-envs", type=int, default=4096, help="parallel envs")
        parser.add_argument("--steps", type=int, default=200, help="env steps per timed call")
        parser.add_argument(
            "--iterations", type=int, default=20, help="training iterations per timed call"
        )
        parser.add_argument(
            "--decision-steps",
            type=int,
            nargs="+",
            metavar="K",
            help="time training at each env.decision_steps K side by side (default: the config's)",
        )
        _config_options(parser)
    elif args.name == "all":
        parser.add_argument("--repeats", type=int)
        parser.add_argument("--out", metavar="DIR")
        parser.add_argument("--quick", action="store_true")
    if args.name in ("quick", "all"):
        args.options = parser.parse_args(args.args)
    return cmd_bench(args)


#: name -> (what runs it, its docstring the help text: a summary, then the description;
#: what adds its options; the help of its --quiet).
COMMANDS: dict[str, tuple[Callable[[argparse.Namespace], int], Callable[[Parser], None], str]] = {
    "train": (cmd_train, _train_options, "no progress bar"),
    "evaluate": (cmd_evaluate, _evaluate_options, "no status messages on stderr"),
    "reproduce": (cmd_reproduce, _reproduce_options, "no progress bar"),
    "replay": (cmd_replay, _replay_options, "no line per episode"),
    "export": (cmd_export, _export_options, "no status message"),
    "sweep": (cmd_sweep, _sweep_options, "no progress bar"),
    "study": (cmd_study, _study_options, "no progress bars"),
    "frontier": (cmd_frontier, _frontier_options, "no status messages"),
    "report": (cmd_report, _report_options, "no status messages"),
    "bench": (_bench, _bench_options, ""),  # its options are the benchmark's
}


def build_parser() -> Parser:
    """The ``drqn-jax`` parser: one subparser per command."""
    parser = Parser(
        prog="drqn-jax",
        description="JAX DRQN for urban driving among pedestrians (Deshpande et al.)",
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"drqn-jax {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (handler, add_options, quiet) in COMMANDS.items():
        summary, _, doc = (inspect.getdoc(handler) or "").partition("\n\n")
        summary = " ".join(summary.split())
        command = sub.add_parser(name, help=summary, description=doc, formatter_class=_Formatter)
        add_options(command)
        if quiet:
            command.add_argument("--quiet", action="store_true", help=quiet)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``drqn-jax`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    args.command_line = shlex.join(["drqn-jax", *(sys.argv[1:] if argv is None else argv)])
    try:
        return COMMANDS[args.command][0](args)
    except (ConfigError, CheckpointError) as err:
        print(f"drqn-jax {args.command}: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:  # outside training (compiling, evaluating): nothing to save
        print(f"drqn-jax {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
