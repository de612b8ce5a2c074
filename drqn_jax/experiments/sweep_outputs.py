"""What a sweep writes under its output directory, and how it is read back::

OUT/plan.json                      the points (values, training hash) and processes
OUT/calls/runs-<first>-<last>/     checkpoint.npz/.json while a call runs, then runs.json
OUT/metrics/run-<index>.csv        each run's training metrics, one row per episode
OUT/agents/run-<index>/            each run's agent (config.toml, agent.npz)
OUT/results.md, results.csv        per setting: mean, std, 95 % interval, IQM
OUT/runs.json                      every run's evaluation and training summary"""

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from drqn_jax.experiments.checkpoint import (
    CHECKPOINT_JSON,
    CHECKPOINT_NPZ,
    CheckpointError,
    atomic_write_text,
)
from drqn_jax.experiments.runner import save_agent
from drqn_jax.experiments.sweep import Sweep
from drqn_jax.experiments.sweep_plan import Call, Distributed
from drqn_jax.learners import TrainState


def _check_plan(path: Path, record: dict[str, Any]) -> None:
    """Check ``path`` holds this sweep or its first points (same training hashes)."""
    out = path.parent
    if not path.is_file():
        raise CheckpointError(f"{out}: no sweep to resume (no {path.name})")
    saved = json.loads(path.read_text())
    if saved.get("processes") != record["processes"]:
        raise CheckpointError(
            f"{out}: the sweep ran as {saved.get('processes')} process(es); resume it with as many"
        )
    new = {p["index"]: p for p in record["points"]}
    for point in saved.get("points", []):
        if new.get(point["index"], {}).get("training_hash") != point["training_hash"]:
            raise CheckpointError(
                f"{out} holds another sweep: point {point['index']} ({point['values']}) "
                "differs or is missing; resume with the same sweep file and --set overrides "
                "(more points may follow the saved ones, none may change)"
            )


def open_plan(out: Path, sweep: Sweep, dist: Distributed, resume: bool) -> None:
    """Write ``OUT/plan.json`` for a new sweep, or check and rewrite it (with any new
    points) for a resumed one."""
    points = [
        {"index": p.index, "values": p.values, "training_hash": p.config.training_hash()}
        for p in sweep.points
    ]
    record = {"base": sweep.base, "axes": sweep.axes, "processes": dist.processes, "points": points}
    # one plan per process when there are several (no shared file system needed)
    plan = out / ("plan.json" if dist.processes == 1 else f"plan.process-{dist.process}.json")
    if resume:
        _check_plan(plan, record)
    elif plan.exists():
        raise CheckpointError(
            f"{out} already holds a sweep; continue it with --resume or choose another --out"
        )
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(plan, json.dumps(record, indent=1) + "\n")


def metrics_path(out: str | Path, index: int) -> Path:
    """``OUT/metrics/run-NNNN.csv``: the training metrics of the sweep's run ``index``."""
    return Path(out) / "metrics" / f"run-{index:04d}.csv"


def agent_dir(out: str | Path, index: int) -> Path:
    """``OUT/agents/run-NNNN``: run ``index``'s agent, read like a run directory."""
    return Path(out) / "agents" / f"run-{index:04d}"


def write_agents(out: Path, call: Call, state: TrainState, params: Any) -> None:
    """Each run's trained agent (the evaluated ``params``) at :func:`agent_dir`."""
    names = ("recorded", "grad_steps", "env_steps")
    counts = {name: np.asarray(getattr(state, name)) for name in names}
    for i, point in enumerate(call.points):
        meta = {"values": point.values, "finished": True}
        meta |= {name: int(count[i]) for name, count in counts.items()}
        run_params = jax.tree.map(lambda x, i=i: x[i], params)
        save_agent(agent_dir(out, point.index), point.config, run_params, meta)


#: A finished call's training wall time, kept apart from its deterministic ``runs.json``.
TIMING_JSON = "timing.json"


def write_call(
    out: Path,
    call: Call,
    results: Sequence[dict[str, Any]],
    metrics_csvs: Sequence[str],
    wall_time_s: float | None,
) -> None:
    """A finished call: each run's ``metrics.csv`` (as ``drqn-jax train`` writes it) at
    :func:`metrics_path`, ``calls/<call>/timing.json`` (training wall time, s, and its runs)
    and, last, its ``runs.json`` (replacing its checkpoint)."""
    for point, text in zip(call.points, metrics_csvs, strict=True):
        path = metrics_path(out, point.index)
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, text)
    call_dir = out / "calls" / call.name
    call_dir.mkdir(parents=True, exist_ok=True)
    timing = {"train_wall_s": wall_time_s, "runs": [p.index for p in call.points]}
    atomic_write_text(call_dir / TIMING_JSON, json.dumps(timing, indent=1) + "\n")
    atomic_write_text(call_dir / "runs.json", json.dumps(list(results), indent=1) + "\n")
    for name in (CHECKPOINT_NPZ, CHECKPOINT_JSON):  # the results replace them
        (call_dir / name).unlink(missing_ok=True)


def run_timings(directory: Path) -> dict[int, float]:
    """By run index, its share (s) of its call's training wall time, where recorded."""
    timings: dict[int, float] = {}
    for path in sorted((directory / "calls").glob(f"*/{TIMING_JSON}")):
        record = json.loads(path.read_text())
        wall, indices = record["train_wall_s"], record["runs"]
        timings.update((i, wall / len(indices)) for i in indices)
    return timings


def finished_results(directory: Path) -> list[dict[str, Any]]:
    """The runs of a config's sweep whose call has ended (``calls/*/runs.json``), by index."""
    results: dict[int, dict[str, Any]] = {}  # by index: a grown plan may regroup its calls
    for path in sorted((directory / "calls").glob("*/runs.json")):
        results.update((r["index"], r) for r in json.loads(path.read_text()))
    return [results[i] for i in sorted(results)]


def run_record(directory: str | Path) -> dict[str, Any] | None:
    """The ``runs.json`` record of the sweep run whose :func:`agent_dir` is ``directory``;
    None if it is not one (e.g. a ``drqn-jax train`` run)."""
    path = Path(directory)
    index = path.name.removeprefix("run-")
    if path.parent.name != "agents" or not index.isdigit():
        return None
    found = [r for r in finished_results(path.parent.parent) if r["index"] == int(index)]
    return found[0] if found else None
