"""``drqn-jax train``, ``evaluate``, ``reproduce``, ``replay``, ``export``: one run."""

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from drqn_jax.agents import drqn_agent
from drqn_jax.agents.shipped import shipped_agent_dir, shipped_agents
from drqn_jax.commands import default_run_dir, episodes_text, evaluation_overrides, say
from drqn_jax.config import Config, ConfigError, load_config
from drqn_jax.evaluation import metrics_table
from drqn_jax.experiments.machine import device_identity
from drqn_jax.experiments.runner import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    builtin_agent,
    evaluate_agents,
    json_ready,
    load_run,
    load_trained_network,
    recorded_metrics,
    train_run,
    write_evaluation,
)
from drqn_jax.learners.common import selection
from drqn_jax.learners.hyperparams import agent_name


def cmd_train(args: argparse.Namespace) -> int:
    """Train the DRQN

    Train the DRQN of a config; writes config.toml, metrics.csv, checkpoints,
    evaluation.json and results.md to the run directory. Ctrl-C (or SIGTERM) saves a
    checkpoint and exits with status 130; --resume continues bit-identically.
    """
    start = time.perf_counter()
    if args.resume is None:
        config = load_config(args.config, args.overrides)
        run_dir = Path(args.run_dir or default_run_dir("train", args.config))
    elif args.config != "default" or args.run_dir is not None:
        raise ConfigError(
            "--resume RUN_DIR continues with RUN_DIR's own config.toml and directory: "
            "drop --config and --run-dir (use --set for non-training fields)"
        )
    else:
        config = load_run(args.resume, tuple(args.overrides))
        run_dir = Path(args.resume)
    return _train_and_evaluate(args, config, run_dir, start, resume=args.resume is not None)


def _train_and_evaluate(
    args: argparse.Namespace,
    config: Config,
    run_dir: Path,
    start: float,
    resume: bool = False,
    reproduce: bool = False,
) -> int:
    """Train, then evaluate the DRQN (to reproduce Table III, beside the rule-based agent);
    --rrd: the training curves, written once training stops, however it stops."""
    rrd, quiet = args.rrd, args.quiet
    if rrd is not None and Path(rrd).is_dir():
        raise ConfigError(f"--rrd {rrd}: is a directory; give a file name such as training.rrd")
    result = train_run(config, run_dir, resume=resume, quiet=quiet)
    state = result.state
    if rrd is not None:
        from drqn_jax.interop.recording import record_training

        try:
            record_training(rrd, recorded_metrics(state))
            say(f"training curves: {rrd} (view with: rerun {rrd})")
        except OSError as err:  # the run itself is saved: report and go on
            say(f"error: --rrd {rrd}: {err}")
    if result.status != "finished":
        say(("error: " if result.status == "diverged" else "") + result.message)
        return EXIT_FAILED if result.status == "diverged" else EXIT_INTERRUPTED
    summary = {
        "run_dir": str(result.run_dir),
        "train_wall_time_s": result.wall_time_s,
        "compile_time_s": result.compile_time_s,
        "episodes": int(state.recorded),
        "env_steps": int(state.env_steps),
        "grad_steps": int(state.grad_steps),
        **selection(state.validation, state.hparams),
    }
    about = (
        f"training {result.wall_time_s:.1f} s over {int(state.recorded)} episodes, "
        f"{int(state.grad_steps)} gradient steps"
    )
    params = result.trainer.agent_params(state)
    agent = drqn_agent(result.trainer.network, params, agent_name(result.trainer.config))
    training = None
    if reproduce:
        training = {"env_steps": int(state.env_steps), "trained_on": device_identity()}
        training["train_wall_s"] = result.wall_time_s
    return _evaluated(config, agent, run_dir, quiet, start, summary, about, training)


def _evaluated(
    config: Config,
    agent: Any,
    run_dir: Path,
    quiet: bool,
    start: float,
    summary: dict[str, Any],
    about: str,
    training: dict[str, Any] | None = None,
) -> int:
    """Evaluate ``agent``, write it to ``run_dir``, print its table and the wall time; with
    ``training`` (Table III) beside the rule-based agent and its frontier on the same episodes
    (swept in a second thread to fill idle cores; each program's output is what it gives alone)."""
    agents = [agent] if training is None else [agent, builtin_agent("rule-based", config)]
    if not quiet:
        if training is not None:
            say("sweeping the rule-based frontier on the same episodes...")
        say(f"evaluating {' and '.join(a.name for a in agents)} on {episodes_text(config)}...")
    if training is None:
        results = evaluate_agents(config, agents, quiet=quiet)
        table = metrics_table(results)
    else:
        from drqn_jax.experiments.baselines import config_frontier
        from drqn_jax.experiments.curves import plot_safety_speed

        with ThreadPoolExecutor(max_workers=1) as pool:
            swept = pool.submit(config_frontier, config, planner=False)
            results = evaluate_agents(config, agents, quiet=quiet)
            frontier = swept.result()
        trained = {**results[0], **training}
        rows, table = paper_comparison(
            trained, results[1], frontier, config["env"]["decision_steps"]
        )
        run_dir.mkdir(parents=True, exist_ok=True)
        plot_safety_speed(rows, frontier, run_dir / "safety_speed.png")
    wall = time.perf_counter() - start
    write_evaluation(run_dir, results, {**summary, "total_wall_time_s": wall}, table)
    print(table + "\n")
    if training is not None:
        print(f"safety/speed figure: {run_dir / 'safety_speed.png'}")
    print(f"wall time {wall:.1f} s ({about})\nrun directory: {run_dir}")
    return EXIT_OK


def _chosen_agent(args: argparse.Namespace, overrides: list[str]) -> tuple[Config, Any, Any, Any]:
    """``(config, agent, network, network_params)`` for ``[RUN_DIR] --agent``: a trained
    or shipped agent from its last checkpoint (``overrides`` apply to the episodes only),
    or a built-in agent (``network`` None) on the run's config or ``--config``."""
    run_dir, chosen = args.run_dir, args.agent or ("drqn" if args.run_dir else "rule-based")
    if chosen in shipped_agents():
        if run_dir is not None:
            raise ConfigError(f"--agent {chosen} is a shipped agent: give no RUN_DIR")
        run_dir, chosen = str(shipped_agent_dir(chosen)), "drqn"
    if chosen != "drqn":
        config = (
            load_run(run_dir, tuple(overrides)) if run_dir else load_config(args.config, overrides)
        )
        return config, builtin_agent(chosen, config), None, None
    if run_dir is None:
        raise ConfigError("--agent drqn needs a RUN_DIR (a trained run)")
    network, params, meta = load_trained_network(load_run(run_dir, ()), run_dir)
    if not meta["finished"]:
        say(f"note: {run_dir} has not finished training ({meta['recorded']} episodes so far)")
    config = load_run(run_dir, tuple(overrides))
    name = agent_name(config.train_config())
    return config, drqn_agent(network, params, name), network, params


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Evaluate a trained run or a built-in agent

    Evaluate a run directory's DRQN (or a sweep's or study's trained agent,
    OUT/agents/run-NNNN) or a built-in agent greedily on the evaluation key and print the
    SPEC §8 metrics. --set changes the episodes, not the agent: e.g. --set env.id=...
    evaluates it among other pedestrians, --seed 0 on a study's episodes.
    """
    overrides = evaluation_overrides(args.overrides, args.episodes, args.seed)
    config, agent, _, _ = _chosen_agent(args, overrides)
    start = time.perf_counter()
    seed, world = config["run"]["seed"], config["env"]["id"]
    if not args.quiet:
        say(f"evaluating {agent.name} on {episodes_text(config)}...")
    (result,) = evaluate_agents(config, [agent], quiet=args.quiet)
    wall = time.perf_counter() - start
    # with --json - stdout carries only the JSON (pipe it to jq); the table goes to stderr
    table_out = sys.stderr if args.json == "-" else sys.stdout
    print(metrics_table([result]), file=table_out)
    print(
        f"\n{result['num_episodes']} episodes of {world}, evaluation key of seed {seed}, "
        f"{wall:.1f} s",
        file=table_out,
    )
    if args.json is not None:
        text = json.dumps({**json_ready(result), "seed": seed}, indent=2) + "\n"
        if args.json == "-":
            sys.stdout.write(text)
        else:
            Path(args.json).write_text(text)
    return EXIT_OK


def paper_comparison(
    trained: dict[str, Any],
    rule_based: dict[str, Any],
    frontier: dict[str, Any],
    decision_steps: int,
) -> tuple[list[dict[str, Any]], str]:
    """The paper's Table III rows beside ours (the trained agent, deciding every
    ``decision_steps`` ticks, then the rule-based one) with margins to ``frontier`` and the
    verdict on the paper's claim: rows and text."""
    from drqn_jax.experiments.frontier import with_margin
    from drqn_jax.experiments.report import column_legend, study_table
    from drqn_jax.experiments.rows import baseline_row, paper_rows
    from drqn_jax.experiments.verdicts import claim_verdict

    world, limit_kmh = frontier["world"], frontier["speed_limit_kmh"]
    ours = [
        baseline_row("drqn_jax", trained, world=world, decision_steps=decision_steps),
        baseline_row("drqn_jax", rule_based, world=world),
    ]
    ours = [with_margin(row, frontier, limit_kmh) for row in ours]
    rows = paper_rows() + ours
    verdict = claim_verdict(ours[0]) + (
        " One training seed: its interval holds the episodes' variation, not the"
        " training's (drqn-jax study trains several)."
    )
    return rows, "\n\n".join([study_table(rows, legend=False), verdict, column_legend()])


#: The shipped agent ``drqn-jax reproduce`` evaluates (:mod:`drqn_jax.agents.shipped`).
HEADLINE = "headline"


def _headline_dir() -> Path:
    try:
        return shipped_agent_dir(HEADLINE)
    except ValueError as err:
        raise ConfigError(
            f"{err}; train one (drqn-jax train --config NAME) and export it to "
            f"drqn_jax/agents/trained/{HEADLINE} (drqn-jax export)"
        ) from None


def cmd_reproduce(args: argparse.Namespace) -> int:
    """Train, evaluate and print the paper's Table III beside ours

    Evaluate the agent shipped with drqn_jax (--agent headline) and the paper's rule-based
    agent on evaluate.episodes episodes, sweep the rule-based frontier on the same
    episodes, and print the paper's Table III beside ours with each agent's margin to the
    frontier and the verdict on the paper's claim; with --train, of an agent trained again
    first. Writes evaluation.json, results.md and safety_speed.png to the run directory.
    """
    start = time.perf_counter()
    if args.train:
        source = args.config or _headline_dir() / "config.toml"
        config = load_config(source, args.overrides)
        name = Path(str(args.config)).stem if args.config else HEADLINE
        run_dir = Path(args.run_dir or default_run_dir("reproduce", name))
        if not args.quiet:
            from drqn_jax.commands.bench import estimate_lines

            say(estimate_lines([(name, config, 1, "map")]))
        return _train_and_evaluate(args, config, run_dir, start, reproduce=True)
    if args.config is not None or args.rrd is not None:
        raise ConfigError("--config and --rrd are for --train: reproduce alone trains nothing")
    directory = _headline_dir()
    shipped = argparse.Namespace(run_dir=None, agent=HEADLINE, config=None)
    config, agent, _, _ = _chosen_agent(shipped, list(args.overrides))
    provenance = json.loads((directory / "provenance.json").read_text())
    trained = provenance["trained"]
    k = provenance["decision_steps"]
    about = (
        f"the shipped agent {HEADLINE!r}: one decision per {k * config['env']['dt']:g} s "
        f"({k} tick{'s' * (k > 1)}), "
        f"{provenance['env_steps']:,} decisions = {provenance['ticks']:,} ticks, "
        f"trained by `{provenance['command']}` at commit {trained['commit']} "
        f"on {trained['device']}"
    )
    if not args.quiet:
        say(about)
    run_dir = Path(args.run_dir or default_run_dir("reproduce", HEADLINE))
    summary = {"agent_dir": str(directory), "provenance": provenance}
    training = {
        "env_steps": int(provenance["env_steps"]),
        "trained_on": trained["device"],
        "train_wall_s": provenance.get("wall_time_s"),
    }
    return _evaluated(config, agent, run_dir, args.quiet, start, summary, about, training)


def cmd_replay(args: argparse.Namespace) -> int:
    """Record episodes of a trained run or a built-in agent for the rerun viewer

    Record episodes of a run directory's greedy DRQN (with its four Q-values per step)
    or of a built-in agent as a rerun recording: the map, the ego, the pedestrians coloured
    by behaviour, the four grid channels, speed, action, reward and TTC on the timeline
    "step". Episode i is episode i of `evaluate`. View it with: rerun PATH
    """
    from drqn_jax.interop.episode_record import collect_episodes
    from drqn_jax.interop.recording import write_episodes

    if args.episodes < 1:
        raise ConfigError(f"--episodes = {args.episodes}: must be an integer >= 1")
    overrides = evaluation_overrides(args.overrides, seed=args.seed)
    config, agent, network, params = _chosen_agent(args, overrides)
    out = Path(args.out or Path(args.run_dir or ".") / "episodes.rrd")
    if out.is_dir():
        raise ConfigError(f"--out {out}: is a directory; give a file name such as episodes.rrd")
    env, env_params = config.make_env()
    _, eval_key = config.keys()
    record = collect_episodes(
        agent, eval_key, args.episodes, env, env_params, network=network, network_params=params
    )
    try:
        write_episodes(out, record, env, env_params)
    except OSError as err:
        raise ConfigError(f"--out {out}: {err.strerror or err}") from None
    for i in range(0 if args.quiet else record.num_episodes):
        print(
            f"episode {i}: {int(record.length[i])} steps, "
            f"return {float(record.episode_return[i]):.2f}, {record.outcome(i)}"
        )
    seed, n = config["run"]["seed"], record.num_episodes
    print(f"wrote {n} episode{'s' if n != 1 else ''} of {agent.name} (seed {seed}) to {out}")
    print(f"view with: rerun {out}")
    return EXIT_OK


def cmd_export(args: argparse.Namespace) -> int:
    """Write a finished run's trained agent alone (a few MB) to a directory

    OUT/config.toml, OUT/agent.npz (its parameters alone, with the config's training hash)
    and OUT/provenance.json (the training command, its figures, and the commit and device
    that trained it: a drqn-jax train run is taken to have trained here, so export it
    there). evaluate and replay read OUT like a run directory; a directory under
    drqn_jax/agents/trained/NAME is shipped with the package as --agent NAME.
    """
    from drqn_jax.experiments.runner import export_agent
    from drqn_jax.experiments.sweep_outputs import run_record

    record = run_record(args.run_dir)  # a sweep run's: where it trained, not where it is now
    trained = (
        None if record is None else {"commit": record["commit"], "device": record["trained_on"]}
    )
    provenance = export_agent(args.run_dir, args.out, args.training_command, trained)
    if not args.quiet:
        steps = provenance.get("env_steps", 0)
        say(f"{args.out}: the agent of {args.run_dir} ({steps:,} env steps), with provenance.json")
    return EXIT_OK
