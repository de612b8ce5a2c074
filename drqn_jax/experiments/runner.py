"""Host-side driver of a training run: chunks, progress, checkpoints, signals, evaluation. It calls
the pure :func:`drqn_jax.learners.make_train` ``run(state, chunk_iterations)`` in chunks; a chunked
(or interrupted and resumed) run ends bit-identical to a one-shot run. A run directory (SPEC §8)
holds ``config.toml``, ``metrics.csv``, ``checkpoint.npz``/``.json``, ``evaluation.json``,
``results.md``."""

import csv
import dataclasses
import functools
import io
import json
import math
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.agents import constant_agent, planner_agent, random_agent, rule_based_agent
from drqn_jax.agents.base import Agent
from drqn_jax.config import Config, ConfigError, load_config
from drqn_jax.evaluation import evaluate
from drqn_jax.experiments.checkpoint import (
    AGENT,
    CHECKPOINT,
    CHECKPOINT_NPZ,
    CheckpointError,
    atomic_write_text,
    load_checkpoint,
    read_manifest,
    save_checkpoint,
    writer,
)
from drqn_jax.experiments.host_loop import StopRequest, finite_training, progress_bar, run_chunks
from drqn_jax.experiments.machine import device_identity, git_commit, machine_info
from drqn_jax.experiments.report import strict_json
from drqn_jax.learners import Trainer, TrainState, make_train
from drqn_jax.learners.hyperparams import LEARNED_AGENTS, NOT_LEARNED, teacher_label
from drqn_jax.networks import Network
from drqn_jax.programs import cached

#: The order of ``metrics.csv``'s columns (a task's other metrics come after, by name).
METRIC_COLUMNS = (
    "episode_return",
    "length",
    "collision",
    "goal",
    "distance",
    "mean_speed",
    "epsilon",
    "mean_loss",
)

#: Exit statuses of the command line.
EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130

_RECENT = 20  # episodes in the progress bar's running means


@dataclasses.dataclass
class RunResult:
    """What :func:`train_run` ended with: ``status`` ``"finished"``, ``"interrupted"``
    (checkpoint saved) or ``"diverged"`` (non-finite loss: the last good checkpoint kept)."""

    status: str
    state: TrainState
    trainer: Trainer
    run_dir: Path
    wall_time_s: float
    compile_time_s: float
    message: str = ""


def init_program(trainer: Trainer) -> Callable[[jax.Array], TrainState]:
    """``init(key) -> TrainState``, jitted with hyperparameters and env params as arguments
    (not constants) so one cached program serves every value of a shape."""
    return functools.partial(
        jax.jit(trainer.init),
        hparams=trainer.config.hyperparams,
        env_params=trainer.task.env_params,
    )


def compiled_run(trainer: Trainer, state: TrainState, iterations: int | None = None) -> Any:
    """``run(state, iterations)``, compiled once per program key and chunk size."""
    chunk = trainer.config.chunk_iterations if iterations is None else iterations

    def build() -> Any:
        return jax.jit(trainer.run, static_argnums=1).lower(state, chunk).compile()

    return cached("runner.run", (trainer.config.program_key(), chunk), build)


def recorded_metrics(state: TrainState | Mapping[str, Any]) -> dict[str, np.ndarray]:
    """Host copies of the ended episodes' metrics (``length`` >= 1), plus ``episode``, from a run's
    ``TrainState`` or its ``metrics`` dict (leaves ``(num_episodes,)``)."""
    source = state if isinstance(state, Mapping) else state.metrics
    metrics = {name: np.asarray(v) for name, v in source.items()}
    done = metrics["length"] > 0
    out = {"episode": np.flatnonzero(done)}
    order = {name: i for i, name in enumerate(METRIC_COLUMNS)}
    columns = sorted(metrics, key=lambda n: (order.get(n, len(order)), n))
    out.update({name: metrics[name][done] for name in columns})
    return out


def final_train_return(metrics: Mapping[str, Any]) -> float:
    """Mean return of the last 10 % (at least one) of a run's recorded episodes; NaN if none."""
    returns = recorded_metrics(metrics)["episode_return"]
    if not len(returns):
        return math.nan
    return float(np.mean(returns[-max(1, len(returns) // 10) :]))


def _format(value: Any) -> str:
    if isinstance(value, np.floating):
        return np.format_float_positional(value, unique=True, trim="-")
    if isinstance(value, np.bool_):
        return str(int(value))
    return str(value)


def metrics_csv(state: TrainState | Mapping[str, Any]) -> str:
    """``metrics.csv`` text: ``episode`` then every training metric (SI units)."""
    rows = recorded_metrics(state)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(rows.keys())
    for i in range(len(rows["episode"])):
        writer.writerow(_format(column[i]) for column in rows.values())
    return out.getvalue()


def _save(run_dir: Path, config: Config, state: TrainState, wall: float, chunks: int) -> None:
    """The checkpoint (the training identity and counters as its meta) and ``metrics.csv``."""
    counts = {k: int(getattr(state, k)) for k in ("recorded", "grad_steps", "env_steps")}
    meta = {"finished": bool(state.finished), "chunks": chunks, "wall_time_s": wall}
    save_checkpoint(run_dir, state, {**config.training_identity(), **counts, **meta})
    atomic_write_text(run_dir / "metrics.csv", metrics_csv(state))


def train_run(
    config: Config, run_dir: str | Path, *, resume: bool = False, quiet: bool = False
) -> RunResult:
    """Train (or, with ``resume``, continue) the run in ``run_dir`` until done or stopped;
    CheckpointError for a fresh run in a used directory or a bad checkpoint on resume."""
    run_dir = Path(run_dir)
    trainer = make_train(config.train_config())
    train_key, _ = config.keys()
    init = init_program(trainer)
    wall_before, chunks = 0.0, 0
    if resume:
        template = jax.eval_shape(init, train_key)
        state, meta = load_checkpoint(run_dir, template, config.training_identity())
        wall_before, chunks = float(meta["wall_time_s"]), int(meta["chunks"])
    else:
        if (run_dir / CHECKPOINT_NPZ).exists():
            raise CheckpointError(
                f"{run_dir} already holds a training run; continue it with --resume {run_dir} "
                "or choose another --run-dir"
            )
        run_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_text(run_dir / "config.toml", config.to_toml())
        state = init(train_key)

    stop = StopRequest()
    with stop.installed():  # a signal while compiling also stops cleanly
        start = time.perf_counter()
        if not quiet:
            print("compiling the training program...", file=sys.stderr, flush=True)
        run = compiled_run(trainer, state)
        compile_s = time.perf_counter() - start
        if not resume:
            _save(run_dir, config, state, 0.0, 0)  # resume works from here on

        def elapsed() -> float:
            return wall_before + time.perf_counter() - start

        status, state, chunks = _chunks(config, run, state, chunks, stop, quiet, run_dir, elapsed)
        if status == "finished":
            state = validated(trainer, state)
    wall = elapsed()
    if status != "diverged":
        _save(run_dir, config, state, wall, chunks)
    num_episodes = config["train"]["num_episodes"]
    message = {
        "finished": "",
        "interrupted": f"interrupted after {int(state.recorded)}/{num_episodes} episodes; "
        f"checkpoint saved, continue with: drqn-jax train --resume {run_dir}",
        "diverged": f"non-finite loss or parameters after episode {int(state.recorded)} "
        f"(chunk {chunks + 1}); the last good checkpoint in {run_dir} is kept",
    }[status]
    return RunResult(status, state, trainer, run_dir, wall, compile_s, message)


def validated(trainer: Trainer, state: TrainState) -> TrainState:
    """``state`` with its snapshots' validation metrics filled in (``train.snapshots`` > 0)."""
    if not trainer.config.snapshots or not bool(jnp.isnan(state.validation["return"]).any()):
        return state
    validate = cached(
        "runner.validate", trainer.config.program_key(), lambda: jax.jit(trainer.validation_metrics)
    )
    return state.replace(validation=validate(state))


def _chunks(
    config: Config,
    run: Any,
    state: TrainState,
    chunks: int,
    stop: StopRequest,
    quiet: bool,
    run_dir: Path,
    elapsed: Callable[[], float],
) -> tuple[str, TrainState, int]:
    """``run_chunks`` for one run: progress bar, periodic checkpoints, stop on non-finite loss."""
    steps = config["train"]["num_env_steps"]  # the bar counts env steps if set, else episodes
    total, unit = (steps, "step") if steps else (config["train"]["num_episodes"], "ep")
    with progress_bar(total, budget_used(state, total, unit), quiet, unit) as bar:
        clock = {"t": time.perf_counter(), "steps": int(state.env_steps)}

        def show(state: TrainState) -> None:  # copies metrics to the host: only when shown
            now, steps = time.perf_counter(), int(state.env_steps)
            steps_per_s = (steps - clock["steps"]) / max(now - clock["t"], 1e-9)
            clock.update(t=now, steps=steps)
            bar.update(budget_used(state, total, unit) - bar.n)
            rows = recorded_metrics(state)
            postfix = {"steps/s": f"{steps_per_s:,.0f}"}
            if len(rows["episode"]):
                postfix["return"] = f"{rows['episode_return'][-_RECENT:].mean():.1f}"
                postfix["collisions"] = f"{100 * rows['collision'][-_RECENT:].mean():.0f}%"
            bar.set_postfix(postfix, refresh=False)

        return run_chunks(
            run,
            state,
            finished=lambda s: bool(s.finished),
            stop=stop,
            save=lambda s, n: _save(run_dir, config, s, elapsed(), n),
            every_s=config["run"]["checkpoint_every_s"],
            healthy=lambda s: bool(finite_training(s)),
            on_chunk=None if quiet else show,
            chunks=chunks,
        )


def budget_used(state: TrainState, total: int, unit: str, runs: int | None = None) -> int:
    """How much of its budget (``total`` in ``unit``) a state (its first ``runs`` runs) has used."""
    used = np.asarray(state.env_steps if unit == "step" else state.recorded)
    return int(np.minimum(used if runs is None else used[:runs], total).sum())


def load_run(run_dir: str | Path, overrides: tuple[str, ...] = ()) -> Config:
    """The configuration stored in a run (or agent) directory, with ``overrides``; CheckpointError
    if it is not a run directory or another format/version wrote it."""
    run_dir = Path(run_dir)
    path = run_dir / "config.toml"
    if not path.is_file():
        raise CheckpointError(f"{run_dir}: not a run directory (no config.toml)")
    saved = [n for n in (CHECKPOINT, AGENT) if (run_dir / f"{n}.npz").is_file()]
    manifest = read_manifest(run_dir, saved[0]) if saved else None  # refuses another format
    try:
        config = load_config(path)
    except ConfigError as err:
        by = f", written by {writer(manifest)}," if manifest else ""
        raise CheckpointError(
            f"{path}{by} does not load in this version: {err}; train it again, "
            "or use the commit that wrote it"
        ) from None
    return load_config(path, overrides) if overrides else config


def load_trained_network(
    config: Config, run_dir: str | Path
) -> tuple[Network, Any, dict[str, Any]]:
    """The network, agent parameters (``Trainer.agent_params``) and checkpoint metadata of a
    run directory, or of a sweep's trained agent (``agent.npz`` only)."""
    trainer = make_train(config.train_config())
    template = jax.eval_shape(trainer.init, config.keys()[0])
    expected = config.training_identity()
    run_dir = Path(run_dir)
    if not (run_dir / CHECKPOINT_NPZ).exists() and (run_dir / f"{AGENT}.npz").exists():
        template = jax.eval_shape(trainer.agent_params, template)
        return trainer.network, *load_checkpoint(run_dir, template, expected, name=AGENT)
    state, meta = load_checkpoint(run_dir, template, expected)
    return trainer.network, trainer.agent_params(state), meta


def save_agent(directory: str | Path, config: Config, params: Any, meta: Mapping[str, Any]) -> None:
    """Write ``config.toml`` and ``agent.npz`` (agent params, no training state) that
    ``evaluate`` and ``replay`` read like a run directory."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    atomic_write_text(directory / "config.toml", config.to_toml())
    save_checkpoint(directory, params, {**config.training_identity(), **meta}, name=AGENT)


#: What an exported agent keeps of its run's checkpoint metadata.
_TRAINING_COUNTS = ("recorded", "grad_steps", "env_steps", "wall_time_s")


def export_agent(
    run_dir: str | Path, out: str | Path, command: str, trained: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """Write a finished run's agent to ``out`` (:func:`save_agent`) with ``provenance.json``
    (command, counters, wall time, the commit/device that trained it, this machine) and return the
    provenance; CheckpointError if the run is missing or unfinished."""
    config = load_run(run_dir)
    _, params, meta = load_trained_network(config, run_dir)
    if not meta["finished"]:
        raise CheckpointError(f"{run_dir}: training has not finished; export a finished run")
    counts = {k: meta[k] for k in _TRAINING_COUNTS if k in meta}
    save_agent(out, config, params, {"finished": True, **counts})
    trained = dict(trained or {"commit": git_commit(), "device": device_identity()})
    k = config["env"]["decision_steps"]  # env steps are decisions of k ticks each
    provenance = {"command": command, **counts, "decision_steps": k}
    provenance.update(ticks=k * counts["env_steps"], trained=trained, machine=machine_info())
    atomic_write_text(Path(out) / "provenance.json", json.dumps(provenance, indent=1) + "\n")
    return provenance


def builtin_agent(name: str, config: Config) -> Agent:
    """``rule-based``, ``planner`` (privileged, SPEC §9), ``random`` or ``accelerate``."""
    agents = {
        "rule-based": lambda: rule_based_agent(config.rule_based_params()),
        "planner": lambda: planner_agent(config.planner_params()),
        "random": random_agent,
        "accelerate": lambda: constant_agent("accelerate"),
    }
    if name not in agents:
        raise ValueError(f"unknown agent {name!r}: rule-based, planner, random or accelerate")
    return agents[name]()


def evaluate_agents(
    config: Config, agents: list[Agent], *, quiet: bool = True
) -> list[dict[str, Any]]:
    """SPEC §8 metrics of each agent on the same evaluation episodes, with its ``teacher``
    (:func:`teacher_label`, or :data:`NOT_LEARNED` for a built-in agent)."""
    env, env_params = config.make_env()
    _, eval_key = config.keys()
    episodes = config["evaluate"]["episodes"]
    learned = teacher_label(config.hyperparams())
    results = []
    for a in agents:
        with progress_bar(episodes, 0, quiet, "episode", f"evaluating {a.name}") as bar:
            show = None if quiet else (lambda done, bar=bar: bar.update(done - bar.n))
            result = evaluate(a, eval_key, episodes, env, env_params, on_episodes=show)
        teacher = learned if a.name in LEARNED_AGENTS else NOT_LEARNED
        results.append({**result, "teacher": teacher})
    return results


def json_ready(result: dict[str, Any]) -> dict[str, Any]:
    """An :func:`evaluate` result without per-episode arrays; non-finite numbers as null."""
    return strict_json({k: v for k, v in result.items() if k != "episodes"})


def write_evaluation(
    run_dir: Path, results: list[dict[str, Any]], extra: dict[str, Any], table: str
) -> None:
    """``evaluation.json`` (results + ``extra``) and ``results.md`` (``table``)."""
    payload = {**extra, "agents": [json_ready(r) for r in results]}
    atomic_write_text(run_dir / "evaluation.json", json.dumps(payload, indent=2) + "\n")
    atomic_write_text(run_dir / "results.md", table + "\n")
