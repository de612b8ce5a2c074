"""A study's runs store: its finished runs in a file of their own, so that a study
outlives its directory.

A study of the paper's protocol trains for hours on a CPU; stopped, it continues
from ``OUT`` (its checkpoints and finished calls). When ``OUT`` is lost (a fresh
clone, another machine, a preemptible machine taken away), the finished runs need
not be: with a runs store (``drqn-jax study --runs-store FILE``; with ``--results``
its default is ``finished-runs/<section>.json`` beside the results file,
:func:`runs_store_path`: ``docs/finished-runs/table3-cpu.json`` for
``docs/results.json``; commit it to carry it to another clone), an interrupted study
keeps each arm's finished runs there (:func:`save_store`): each
run's evaluation record as the sweep saved it, the training hash of its config, and
its training wall time and metrics (``metrics.csv``). The same command in a directory
that holds no such arm writes them back (:func:`restore_runs`) and trains only the
other runs; the table is then the same, bit for bit, as if nothing had stopped
(each run is independent of the others, ``tests/experiments/test_sweep.py``).
A restored run has no trained agent on disk (its parameters are not stored), so
``--eval-envs`` cannot evaluate it. A finished study removes its store
(:func:`drop_store`): the results file's rows hold its results, and the results
file never holds runs.

Store file: ``{"command": the study's command, "finished_runs": {arm: [run, ...]}}``,
each run as :func:`portable_runs` gives it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jax

from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.sweep import Sweep
from drqn_jax.experiments.sweep_outputs import (
    finished_results,
    metrics_path,
    plan_record,
    run_timings,
    write_timing,
)
from drqn_jax.experiments.sweep_plan import plan_calls

__all__ = [
    "differing_runs",
    "drop_store",
    "load_store",
    "portable_runs",
    "restore_runs",
    "runs_store_path",
    "save_store",
]


def runs_store_path(results: str | Path, section: str) -> Path:
    """The default runs store of ``section`` of the results file ``results``:
    ``finished-runs/<section>.json`` in the results file's directory."""
    return Path(results).parent / "finished-runs" / f"{section}.json"


def load_store(path: str | Path) -> dict[str, list[dict[str, Any]]]:
    """The finished runs (arm name → runs) a study kept at ``path``; none where no file."""
    path = Path(path)
    if not path.is_file():
        return {}
    return json.loads(path.read_text())["finished_runs"]


def save_store(
    path: str | Path, finished: Mapping[str, Sequence[Mapping[str, Any]]], command: str
) -> None:
    """Keep ``finished`` (arm name → :func:`portable_runs`) and the study's ``command``
    as the runs store at ``path`` (replacing what it held)."""
    record = {"command": command, "finished_runs": {k: list(v) for k, v in finished.items()}}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(path), json.dumps(record, indent=1) + "\n")


def drop_store(path: str | Path) -> None:
    """Remove the runs store at ``path`` (a finished study's: its rows hold the results)."""
    Path(path).unlink(missing_ok=True)


def portable_runs(directory: Path, sweep: Sweep) -> list[dict[str, Any]]:
    """The finished runs of ``sweep`` in ``directory`` (``OUT/<arm>``), by index: each
    run's record (with the commit and device that trained it) with its training hash,
    its training wall time (``train_wall_s``, :func:`run_timings`; None where not
    counted) and its ``metrics.csv`` text; runs whose metrics are missing are left out."""
    hashes = {p.index: p.config.training_hash() for p in sweep.points}
    timings = run_timings(directory)
    runs = []
    for record in finished_results(directory):
        metrics = metrics_path(directory, record["index"])
        if record["index"] not in hashes or not metrics.is_file():
            continue
        runs.append(
            {
                **record,
                "training_hash": hashes[record["index"]],
                "train_wall_s": timings.get(record["index"]),
                "metrics_csv": metrics.read_text(),
            }
        )
    return runs


def restore_runs(directory: Path, sweep: Sweep, stored: Sequence[Mapping[str, Any]]) -> int:
    """Write ``stored`` runs (:func:`portable_runs`) back into ``directory`` as the
    finished calls of ``sweep``'s plan, if ``directory`` holds no sweep yet; returns
    how many runs were restored.

    A run is restored when its index is one of the sweep's points with the same
    training hash and evaluation episode count; a planned call is restored only
    when all its runs are (on a CPU each call holds one run), the others train.
    """
    if (directory / "plan.json").exists() or not stored:
        return 0
    points = {p.index: p for p in sweep.points}
    usable = {}
    for run in stored:
        point = points.get(run.get("index"))
        if point is None or run.get("training_hash") != point.config.training_hash():
            continue
        if run.get("num_episodes") != point.config["evaluate"]["episodes"]:
            continue
        usable[run["index"]] = run
    calls = plan_calls(sweep, len(jax.local_devices()))
    restored = [c for c in calls if all(p.index in usable for p in c.points)]
    if not restored:
        return 0
    directory.mkdir(parents=True, exist_ok=True)
    atomic_write_text(directory / "plan.json", json.dumps(plan_record(sweep), indent=1) + "\n")
    for call in restored:
        runs = [usable[p.index] for p in call.points]
        for run in runs:
            path = metrics_path(directory, run["index"])
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, run["metrics_csv"])
        apart = ("metrics_csv", "train_wall_s")
        saved = [{k: v for k, v in run.items() if k not in apart} for run in runs]
        call_dir = directory / "calls" / call.name
        call_dir.mkdir(parents=True, exist_ok=True)
        walls = [run.get("train_wall_s") for run in runs]
        write_timing(call_dir, call, None if None in walls else sum(walls))
        atomic_write_text(call_dir / "runs.json", json.dumps(saved, indent=1) + "\n")
    return sum(len(c.points) for c in restored)


def differing_runs(directory: Path, sweep: Sweep, stored: Sequence[Mapping[str, Any]]) -> list[int]:
    """Indices of the finished runs in ``directory`` whose record ``stored`` (the runs
    store's, same index and training hash) holds otherwise. A continued study keeps the
    directory's and stores them again, so a runs store edited alone would be
    overwritten: the study says so (:func:`~drqn_jax.experiments.study.run_study`)."""
    kept = {run.get("index"): run for run in stored}
    return [
        run["index"]
        for run in portable_runs(directory, sweep)
        if run["index"] in kept
        and kept[run["index"]].get("training_hash") == run["training_hash"]
        and kept[run["index"]] != run
    ]
