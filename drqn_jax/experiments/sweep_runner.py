"""Running a sweep: a **call** trains several runs of one program together (``jit(vmap(run))``,
the run axis sharded over the devices, padded to their count) chunk by chunk, checkpointing like
``drqn-jax train``; each run is bit-identical to the same run alone. With several processes each
trains its slice and process 0 gathers results via ``jax.distributed``'s key-value store.
Output layout: :mod:`drqn_jax.experiments.sweep_outputs`."""

import dataclasses
import functools
import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from drqn_jax.agents import drqn_agent
from drqn_jax.evaluation import evaluate
from drqn_jax.experiments.checkpoint import CHECKPOINT_NPZ, load_checkpoint, save_checkpoint
from drqn_jax.experiments.host_loop import StopRequest, finite_training, progress_bar, run_chunks
from drqn_jax.experiments.machine import device_identity, git_commit
from drqn_jax.experiments.runner import budget_used, final_train_return, json_ready, metrics_csv
from drqn_jax.experiments.sweep import Sweep, budget_warnings
from drqn_jax.experiments.sweep_outputs import open_plan, write_agents, write_call
from drqn_jax.experiments.sweep_plan import Call, Distributed, plan_calls
from drqn_jax.learners import Trainer, TrainState, make_train
from drqn_jax.learners.common import selection, unvalidated
from drqn_jax.learners.hyperparams import agent_name, teacher_label
from drqn_jax.programs import cached

_GATHER_TIMEOUT_MS = 2**31 - 1  # process 0 waits for the others as long as they train


# ----------------------------------------------------------------------------- a call


def _stack(trees: Sequence[Any]) -> Any:
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


def _rows(tree: Any, n: int) -> list[Any]:
    """The first ``n`` runs of a batched ``tree``, one NumPy tree each."""
    tree = jax.tree.map(np.asarray, tree)
    return [jax.tree.map(lambda x, i=i: x[i], tree) for i in range(n)]


def _sharding(devices: Sequence[Any]) -> NamedSharding:
    return NamedSharding(Mesh(np.asarray(devices), ("runs",)), PartitionSpec("runs"))


def call_inputs(call: Call, devices: Sequence[Any]) -> tuple[tuple[Any, Any, Any], jax.Array]:
    """``(keys, hparams, env_params)`` stacked and padded to ``call.size`` (copies of the
    last run), and ``real`` flags ``(size,)`` (False for padding), sharded over ``devices``."""
    padded = [*call.points, *[call.points[-1]] * (call.size - len(call.points))]
    keys = jnp.stack([p.config.keys()[0] for p in padded])
    hparams = _stack([p.config.hyperparams() for p in padded])
    env_params = _stack([p.config.make_env()[1] for p in padded])
    real = np.arange(call.size) < len(call.points)
    return (keys, hparams, env_params), jax.device_put(real, _sharding(devices))


def _over_runs(
    fn: Callable[[TrainState], Any],
    skipped: Callable[[TrainState, jax.Array], Any],
    devices: Sequence[Any],
    strategy: str,
    **jit_options: Any,
) -> Callable:
    """``program(states, real)``: ``fn`` per run, ``shard_map`` over devices, then ``vmap``
    or ``map`` (where ``skipped`` runs cost nothing, via ``lax.cond``)."""
    runs = PartitionSpec("runs")

    def batched(states: TrainState, real: jax.Array) -> Any:
        return jax.vmap(fn)(states)

    def one_by_one(states: TrainState, real: jax.Array) -> Any:
        return jax.lax.map(lambda args: skipped(*args), (states, real))

    body = batched if strategy == "vmap" else one_by_one
    mesh = _sharding(devices).mesh
    # no collectives: each device's runs are independent (check_vma off, as
    # the env's lax.cond branches mix per-device and replicated values)
    program = jax.shard_map(body, mesh=mesh, in_specs=(runs, runs), out_specs=runs, check_vma=False)
    return jax.jit(program, **jit_options)


def call_programs(
    trainer: Trainer, size: int, devices: Sequence[Any], strategy: str
) -> tuple[Callable, Callable, Callable]:
    """``(init, run, validate)`` of a call, jitted once per process and shape (hyperparameters
    are arguments/state, so calls differing only in values share them): ``init(keys, hparams,
    env_params)`` -> the batched state; ``run(state, real)`` advances each real, unfinished run
    a chunk; ``validate(state, real) -> {metric: (size, K + 1)}``, ``train.snapshots`` = K > 0."""
    chunk = trainer.config.chunk_iterations

    def build() -> tuple[Callable, Callable, Callable]:

        def advance(state: TrainState) -> TrainState:
            return trainer.run(state, chunk)

        def advance_unless_done(state: TrainState, is_real: jax.Array) -> TrainState:
            return jax.lax.cond(is_real & ~state.finished, advance, lambda s: s, state)

        def validate_if_real(state: TrainState, is_real: jax.Array) -> dict[str, jax.Array]:
            nan = unvalidated(trainer.config.snapshots, trainer.task.validation_metrics)
            return jax.lax.cond(is_real, trainer.validation_metrics, lambda s: nan, state)

        init = jax.jit(jax.vmap(trainer.init), out_shardings=_sharding(devices))
        run = _over_runs(advance, advance_unless_done, devices, strategy, donate_argnums=0)
        validate = _over_runs(trainer.validation_metrics, validate_if_real, devices, strategy)
        return init, run, validate

    key = (trainer.config.program_key(), size, tuple(devices), strategy)
    return cached("sweep_runner.call", key, build)


@dataclasses.dataclass
class CallOutcome:
    """How a call ended: ``finished`` or ``interrupted`` (checkpoint saved)."""

    status: str
    trainer: Trainer
    state: TrainState  # batched, padding included
    wall_time_s: float = 0.0  # s, over every invocation, compile and validation included


def train_call(
    call: Call,
    devices: Sequence[Any],
    *,
    directory: Path | None = None,
    checkpoint_every_s: float = math.inf,
    stop: StopRequest | None = None,
    on_chunk: Callable[[TrainState], None] | None = None,
) -> CallOutcome:
    """Train the call's runs to the end, chunk by chunk, sharded over ``devices``; with
    ``directory``, resume from its checkpoint and save every ``checkpoint_every_s`` and on
    ``stop`` (outcome ``interrupted``)."""
    start = time.perf_counter()
    trainer = make_train(call.points[0].config.train_config())
    init, run, validate = call_programs(trainer, call.size, devices, call.strategy)
    args, real = call_inputs(call, devices)
    if directory is not None and (directory / CHECKPOINT_NPZ).exists():
        template = jax.eval_shape(init, *args)
        expected = {"config_hash": call.fingerprint()}
        state, meta = load_checkpoint(directory, template, expected)
        state = jax.device_put(state, _sharding(devices))
        before = float(meta["wall_time_s"])
    else:
        state, before = init(*args), 0.0

    def wall() -> float:
        return before + time.perf_counter() - start

    status, state, _ = run_chunks(
        lambda state: run(state, real),
        state,
        finished=lambda state: bool(jnp.all(state.finished)),
        stop=StopRequest() if stop is None else stop,
        save=lambda state, _: _save_call(directory, call, state, wall()),
        every_s=checkpoint_every_s if directory is not None else math.inf,
        on_chunk=on_chunk,
    )
    if status == "interrupted":
        _save_call(directory, call, state, wall())
        return CallOutcome("interrupted", trainer, state, wall())
    if trainer.config.snapshots:
        state = state.replace(validation=validate(state, real))
    return CallOutcome("finished", trainer, state, wall())


def _save_call(directory: Path | None, call: Call, state: TrainState, wall: float) -> None:
    if directory is not None:
        meta = {"config_hash": call.fingerprint(), "runs": [p.index for p in call.points]}
        save_checkpoint(directory, state, {**meta, "wall_time_s": wall})


def real_agent_params(call: Call, outcome: CallOutcome) -> Any:
    """The call's agent parameters without padding: NumPy leaves ``(len(call.points), ...)``."""
    n = len(call.points)
    params = jax.vmap(outcome.trainer.agent_params)(outcome.state)
    return jax.tree.map(lambda x: np.asarray(x)[:n], params)


def call_results(
    call: Call, outcome: CallOutcome, eval_key: jax.Array, params: Any, commit: str
) -> list[dict[str, Any]]:
    """Per run: index, axis values, SPEC §8 evaluation of its greedy DRQN on ``eval_key``'s
    episodes (as ``evaluate``), final return, env steps, device, commit and divergence;
    nothing that differs between two trainings (wall time is kept apart)."""
    state, device = outcome.state, device_identity()
    finite = jax.vmap(finite_training)(state)
    runs = (state.metrics, state.validation, state.hparams, state.env_steps, finite, params)
    results = []
    for point, run in zip(call.points, _rows(runs, len(call.points)), strict=True):
        metrics, validation, hparams, env_steps, run_finite, run_params = run
        env, env_params = point.config.make_env()
        name = agent_name(point.config.train_config())
        agent = drqn_agent(outcome.trainer.network, run_params, name)
        episodes = point.config["evaluate"]["episodes"]
        evaluation = evaluate(agent, eval_key, episodes, env, env_params)
        evaluation["teacher"] = teacher_label(point.config.hyperparams())
        results.append(
            {
                "index": point.index,
                "values": point.values,
                "final_train_return": final_train_return(metrics),
                "env_steps": int(env_steps),
                "trained_on": device,
                "commit": commit,
                "diverged": not bool(run_finite),
                **selection(validation, hparams),
                **json_ready(evaluation),
            }
        )
    return results


# ------------------------------------------------------------------------------ the sweep


@dataclasses.dataclass
class SweepOutcome:
    """``finished`` (``results``: all runs on process 0) or ``interrupted``; ``continued``:
    an earlier invocation had begun or finished some of this process's calls."""

    status: str
    results: list[dict[str, Any]]
    continued: int = 0


def run_sweep(
    sweep: Sweep,
    out: str | Path,
    *,
    calls: Sequence[Call] | None = None,
    dist: Distributed = Distributed(),
    resume: bool = False,
    quiet: bool = False,
    keep_agents: bool = True,
    on_call_finished: Callable[[], None] | None = None,
) -> SweepOutcome:
    """Train and evaluate this process's runs call by call; gather on process 0. ``resume``
    keeps ended calls the plan still has (points may grow, e.g. more seeds);
    ``on_call_finished`` is called as each call's results reach disk."""
    out = Path(out)
    devices, commit = jax.local_devices(), git_commit()  # HEAD may move while runs train
    if calls is None:
        calls = plan_calls(sweep, len(devices), dist)
    open_plan(out, sweep, dist, resume)
    eval_key = sweep.points[0].config.keys()[1]
    every = sweep.points[0].config["run"]["checkpoint_every_s"]
    results: list[dict[str, Any]] = []
    budgets, unit = sweep_budgets(calls)
    stop = StopRequest()
    desc = f"sweep (process {dist.process})" if dist.processes > 1 else "sweep"
    bar = progress_bar(sum(budgets), 0, quiet or not dist.leader, unit, desc)
    with stop.installed(), bar:
        done = continued = 0
        for call, budget in zip(calls, budgets, strict=True):
            directory = out / "calls" / call.name
            saved = directory / "runs.json"
            continued += resume and (saved.is_file() or (directory / CHECKPOINT_NPZ).is_file())
            if resume and saved.is_file():
                results += json.loads(saved.read_text())
            else:
                n = len(call.points)
                progress = functools.partial(_show_progress, bar, done, budget // n, n, unit)
                outcome = train_call(
                    call,
                    devices,
                    directory=directory,
                    checkpoint_every_s=every,
                    stop=stop,
                    on_chunk=None if bar.disable else progress,  # no host copy unless shown
                )
                if outcome.status == "interrupted":
                    return SweepOutcome("interrupted", results, continued)
                results += _finish_call(out, call, outcome, eval_key, commit, keep_agents)
            done += budget
            bar.update(done - bar.n)
            if on_call_finished is not None:
                on_call_finished()
    if dist.processes > 1:
        results = _gather(results, dist)
    results = sorted(results, key=lambda r: r["index"])
    return SweepOutcome("finished", results, continued)


def _show_progress(bar: Any, done: int, per_run: int, n: int, unit: str, state: TrainState) -> None:
    bar.update(done + budget_used(state, per_run, unit, n) - bar.n)


def _finish_call(
    out: Path,
    call: Call,
    outcome: CallOutcome,
    eval_key: jax.Array,
    commit: str,
    keep_agents: bool,
) -> list[dict[str, Any]]:
    """Evaluate a trained call, write its agents and :func:`write_call`; the runs' results."""
    params = real_agent_params(call, outcome)
    results = call_results(call, outcome, eval_key, params, commit)
    for line in budget_warnings(call.points, results):
        print(line, file=sys.stderr)
    if keep_agents:
        write_agents(out, call, outcome.state, params)
    csvs = [metrics_csv(m) for m in _rows(outcome.state.metrics, len(call.points))]
    write_call(out, call, results, csvs, outcome.wall_time_s)
    return results


def sweep_budgets(calls: Sequence[Call]) -> tuple[list[int], str]:
    """Each call's progress-bar budget and the unit: env steps if every call has a step
    budget, else episodes."""
    trains = [call.points[0].config["train"] for call in calls]
    unit = "step" if all(train["num_env_steps"] for train in trains) else "ep"
    name = "num_env_steps" if unit == "step" else "num_episodes"
    return [train[name] * len(call.points) for train, call in zip(trains, calls, strict=True)], unit


def _gather(results: list[dict[str, Any]], dist: Distributed) -> list[dict[str, Any]]:
    """Every process's results on process 0, via the coordination key-value store."""
    from jax._src import distributed

    client = distributed.global_state.client
    client.key_value_set(f"drqn_jax/sweep/results/{dist.process}", json.dumps(results))
    if not dist.leader:
        return results
    gathered = []
    for p in range(dist.processes):
        text = client.blocking_key_value_get(f"drqn_jax/sweep/results/{p}", _GATHER_TIMEOUT_MS)
        gathered += json.loads(text)
    return gathered
