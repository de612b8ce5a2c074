"""A study's runs store: its finished runs in a file of their own, so a study outlives its
directory (``study --runs-store FILE``; default ``finished-runs/<section>.json`` beside the
results file). Restored runs give the same table bit for bit, but have no agent on disk.

Store file: ``{"command": ..., "finished_runs": {arm: [run, ...]}}`` (:func:`portable_runs`).
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
    open_plan,
    run_timings,
    write_call,
)
from drqn_jax.experiments.sweep_plan import Distributed, plan_calls

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
    """``finished-runs/<section>.json`` beside the results file ``results``."""
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
    """Write ``finished`` (arm → :func:`portable_runs`) and ``command`` as the store at ``path``."""
    record = {"command": command, "finished_runs": {k: list(v) for k, v in finished.items()}}
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(path), json.dumps(record, indent=1) + "\n")


def drop_store(path: str | Path) -> None:
    """Remove the runs store at ``path`` (a finished study's: its rows hold the results)."""
    Path(path).unlink(missing_ok=True)


def portable_runs(directory: Path, sweep: Sweep) -> list[dict[str, Any]]:
    """By index, the finished runs of ``sweep`` in ``directory``: record, training hash,
    ``train_wall_s`` and ``metrics.csv`` text (runs without metrics left out)."""
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
    """Write ``stored`` runs back into an empty ``directory`` as finished calls of ``sweep``'s
    plan (matching index, training hash and episode count; whole calls only); returns the
    number restored."""
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
    open_plan(directory, sweep, Distributed(), resume=False)
    for call in restored:
        runs = [usable[p.index] for p in call.points]
        apart = ("metrics_csv", "train_wall_s")
        saved = [{k: v for k, v in run.items() if k not in apart} for run in runs]
        walls = [run.get("train_wall_s") for run in runs]
        wall = None if None in walls else sum(walls)
        write_call(directory, call, saved, [run["metrics_csv"] for run in runs], wall)
    return sum(len(c.points) for c in restored)


def differing_runs(directory: Path, sweep: Sweep, stored: Sequence[Mapping[str, Any]]) -> list[int]:
    """Indices of finished runs in ``directory`` whose record differs from ``stored``'s (the
    directory's win; the study says so)."""
    kept = {run.get("index"): run for run in stored}
    return [
        run["index"]
        for run in portable_runs(directory, sweep)
        if run["index"] in kept
        and kept[run["index"]].get("training_hash") == run["training_hash"]
        and kept[run["index"]] != run
    ]
