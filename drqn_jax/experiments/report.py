"""One machine-readable results file, and the documents that quote it (issue 41).

A study run with ``--results docs/results.json --section NAME`` stores its table's
rows there (:func:`write_results`), beside the command that produced them, its
wall time and the machine. Documents never retype those numbers: a block ::

    <!-- results:NAME -->
    (generated: the section's table, its comparisons and its command)
    <!-- /results -->

is filled from the file by ``drqn-jax report FILE.md …`` (:func:`update_document`),
and ``drqn-jax report --check`` (and the test suite) fails when a document and the
file disagree.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.machine import NOT_RECORDED

__all__ = [
    "PAPER_DRQN_SPEED_KMH",
    "PAPER_EPISODES",
    "PAPER_TABLE_III",
    "PAPER_WORLD",
    "SECTION_NAME",
    "check_section",
    "load_results",
    "margin_cell",
    "render_section",
    "stale_documents",
    "store_finished_runs",
    "strict_json",
    "study_table",
    "update_document",
    "write_results",
]

#: A section's name: letters, digits, '_', '.' and '-'.
SECTION_NAME = re.compile(r"[\w.-]+")
#: A generated block of a document: its section name and its current body.
BLOCK = re.compile(
    rf"(?P<open><!-- results:(?P<section>{SECTION_NAME.pattern}) -->\n)(?P<body>.*?)"
    r"(?P<close><!-- /results -->)",
    re.S,
)


def strict_json(value: Any) -> Any:
    """``value`` with tuples as lists and non-finite floats as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


def check_section(section: str) -> None:
    """ValueError unless ``section`` is a valid section name (:data:`SECTION_NAME`)."""
    if not SECTION_NAME.fullmatch(section):
        raise ValueError(f"--section {section!r}: must be letters, digits, '_', '.' or '-'")


def load_results(path: str | Path) -> dict[str, Any]:
    """The results file (``{"rows": [...], "sections": {...}}``), or an empty one."""
    path = Path(path)
    if not path.is_file():
        return {"rows": [], "sections": {}}
    return json.loads(path.read_text())


def write_results(
    path: str | Path,
    section: str,
    rows: Sequence[Mapping[str, Any]],
    comparisons: Sequence[str],
    about: Mapping[str, Any],
) -> dict[str, Any]:
    """Replace ``section``'s rows of the results file at ``path`` (other sections stay).

    Each row (:func:`drqn_jax.experiments.study.study_row`) gains ``"section"``; ``about`` (the
    command, its wall time, the machine) and ``comparisons`` are stored under
    ``sections[section]``. Returns the whole record written.
    """
    check_section(section)
    record = load_results(path)
    kept = [r for r in record["rows"] if r.get("section") != section]
    record["rows"] = kept + [{"section": section, **r} for r in rows]
    record["sections"][section] = {**about, "comparisons": list(comparisons)}
    return _save_record(path, record)


def _save_record(path: str | Path, record: dict[str, Any]) -> dict[str, Any]:
    """Write the results file's ``record`` (NaN as null) at ``path``; returns what it wrote."""
    record = strict_json(record)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(path), json.dumps(record, indent=1) + "\n")
    return record


def store_finished_runs(
    path: str | Path, section: str, finished: Mapping[str, Any], command: str
) -> None:
    """Keep an interrupted study's finished runs as ``sections[section]["finished_runs"]``
    of the results file at ``path`` (:mod:`drqn_jax.experiments.portable`); the section's
    rows and the rest of it stay (a new section gets ``command``)."""
    check_section(section)
    record = load_results(path)
    about = record["sections"].setdefault(section, {"command": command})
    about["finished_runs"] = dict(finished)
    _save_record(path, record)


def _nan(row: Mapping[str, Any]) -> dict[str, Any]:
    """A stored row with None (JSON's stand-in) back as NaN for the table."""
    return {k: math.nan if v is None else v for k, v in row.items()}


def render_section(record: Mapping[str, Any], section: str) -> str:
    """Markdown of one section: its table, its comparisons and the command beside them."""
    if section not in record["sections"]:
        known = ", ".join(record["sections"]) or "none"
        raise ValueError(f"results section {section!r}: not in the results file (has: {known})")
    about = record["sections"][section]
    if "wall_time_s" not in about:  # interrupted before its table: what has finished
        return _in_progress(about)
    rows = [_nan(r) for r in record["rows"] if r.get("section") == section]
    lines = [study_table(rows), ""]
    lines += [f"* {c}" for c in about.get("comparisons", [])]
    machine = about.get("machine", {})
    went_on = (
        "; earlier invocations trained its runs, the wall time is the last one's"
        if about.get("continued")
        else ""
    )
    lines += [
        "",
        f"Command (wall time {about['wall_time_s'] / 60:.0f} min on {machine.get('usable_cores')} "
        f"cores of {machine.get('cpu_model')}, JAX {machine.get('jax_version')}, "
        f"commit {machine.get('git_commit')}{went_on}):",
        "",
        "```bash",
        about["command"],
        "```",
    ]
    return "\n".join(lines) + "\n"


def _in_progress(about: Mapping[str, Any]) -> str:
    """Markdown of an interrupted study's section (no table yet): its finished runs per
    arm and the command that continues it."""
    finished = about.get("finished_runs", {})
    counts = ", ".join(f"`{arm}` {len(runs)}" for arm, runs in finished.items()) or "none"
    lines = [
        f"**In progress**: no table until every run has finished. Runs finished so far: "
        f"{counts}. The same command continues it, in a fresh clone too (the finished "
        "runs are kept in this section of the results file):",
        "",
        "```bash",
        about["command"],
        "```",
    ]
    return "\n".join(lines) + "\n"


def update_document(text: str, record: Mapping[str, Any]) -> str:
    """``text`` with every ``results:NAME`` block regenerated from ``record``."""

    def filled(match: re.Match[str]) -> str:
        body = render_section(record, match["section"])
        return match["open"] + body + match["close"]

    return BLOCK.sub(filled, text)


def stale_documents(paths: Sequence[str | Path], record: Mapping[str, Any]) -> list[str]:
    """The documents among ``paths`` whose blocks differ from ``record``'s numbers."""
    return [
        str(p) for p in paths if update_document(Path(p).read_text(), record) != Path(p).read_text()
    ]


#: The paper's Table III: agent, collision-free episodes of 10, avg speed (km/h), distance (m).
PAPER_TABLE_III = (
    ("rule-based", 4, 7.79, 82.6),
    ("DRQN", 7, 6.09, 123.1),
)
PAPER_EPISODES = 10
#: The world column of the paper's rows.
PAPER_WORLD = "CARLA (paper)"
#: km/h: the paper's DRQN's average speed (Table III), at or above which the paper's
#: claim is judged (SPEC §9).
PAPER_DRQN_SPEED_KMH = PAPER_TABLE_III[1][2]


def _cell(value: float | None, spec: str, scale: float = 1.0) -> str:
    return "–" if value is None or not math.isfinite(value) else format(scale * value, spec)


def _steps_cell(steps: float | None) -> str:
    """``6.00M``: env steps in millions; – where there are none."""
    return "–" if steps is None or not math.isfinite(steps) else f"{steps / 1e6:.2f}M"


def _wall_cell(row: Mapping[str, Any]) -> str:
    """``31.2``: the mean training minutes of a seed; ``31.2 (2 of 5)`` where only some
    seeds counted theirs (runs from before wall times were kept); – for none."""
    cell = _cell(row.get("train_wall_s_per_seed"), ".1f", 1 / 60)
    counted = row.get("train_wall_seeds")
    if cell != "–" and counted is not None and counted < row["seeds"]:
        cell += f" ({counted} of {row['seeds']})"
    return cell


def _device_legend(rows: Sequence[Mapping[str, Any]]) -> dict[str, str]:
    """Each device the rows' runs trained on → ``[k]``, numbered in the order first seen
    (the table cell names the number; the legend under the table the device)."""
    names = dict.fromkeys(d for r in rows for d in r.get("devices") or {} if d != NOT_RECORDED)
    return {d: f"[{k}]" for k, d in enumerate(names, 1)}


def _device_cell(devices: Mapping[str, int] | None, legend: Mapping[str, str]) -> str:
    """``[1] ×3, [2] ×2``: how many seeds trained on each device; – for none."""
    if not devices:
        return "–"
    return ", ".join(f"{legend.get(d, '?')} ×{n}" for d, n in devices.items())


def margin_cell(row: Mapping[str, Any]) -> str:
    """``+5.2 (+1.0 to +9.4)``: the row's frontier margin in points with its interval
    (– for a row without one: the paper's, measured in another world; "– (above the
    speed limit)" for a row faster than its world's limit, SPEC §9)."""
    if row.get("above_speed_limit"):
        return "– (above the speed limit)"
    margin, interval = row.get("frontier_margin"), row.get("frontier_margin_ci")
    if margin is None or not math.isfinite(margin) or interval is None:
        return "–"
    low, high = (100 * x if x is not None and math.isfinite(x) else math.nan for x in interval)
    return f"{100 * margin:+.1f} ({low:+.1f} to {high:+.1f})"


def study_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: one row per agent; ``± std`` is across seeds."""
    legend = _device_legend(rows)
    header = (
        "| source | agent | teacher | seeds × episodes | env steps / seed "
        "| train wall / seed (min) | device | collision-free % (95 % interval) "
        "| margin to the rule-based frontier, points (95 %) | struck while stopped % "
        "| avg speed (km/h) | authors' speed (km/h) | distance (m) "
        "| distance, collision-free (m) | goal % | collisions / km |"
    )
    lines = [
        header,
        "| --- | --- | --- | ---: | ---: | ---: | --- | --- | --- | ---: | ---: | ---: | ---: "
        "| ---: | ---: | ---: |",
    ]
    for r in rows:
        low, high = r["collision_free_ci"]
        speed = _cell(r["avg_speed_kmh"], ".2f")
        if math.isfinite(r["avg_speed_kmh_std"]):
            speed += f" ± {r['avg_speed_kmh_std']:.2f}"
        seeds = f"{r['seeds']} × {r['episodes']}"
        if r["diverged"]:
            seeds += f" ({r['diverged']} diverged)"
        lines.append(
            f"| {r['label']} | {r['agent']} | {r.get('learned', '–')} | {seeds} "
            f"| {_steps_cell(r.get('env_steps_per_seed'))} "
            f"| {_wall_cell(r)} "
            f"| {_device_cell(r.get('devices'), legend)} "
            f"| {100 * r['collision_free_rate']:.1f} ({100 * low:.1f}–{100 * high:.1f}) "
            f"| {margin_cell(r)} "
            f"| {_cell(r.get('struck_while_stopped_rate'), '.1f', 100.0)} "
            f"| {speed} | {_cell(r.get('avg_speed_authors_kmh'), '.2f')} "
            f"| {_cell(r['avg_distance_m'], '.1f')} "
            f"| {_cell(r['avg_distance_collision_free_m'], '.1f')} "
            f"| {_cell(r['goal_rate'], '.1f', 100.0)} | {_cell(r['collisions_per_km'], '.2f')} |"
        )
    lines += [
        "",
        "Collision-free interval: 95 % Student t of the mean across seeds for a trained "
        "config (training and episodes vary; cut to 0–100 %); Wilson over the episodes "
        "for one policy (the rule-based agent, the paper's 10-episode rows). Margin: the "
        "collision-free rate minus the rule-based family's frontier at the agent's own "
        "average speed (SPEC §9; each seed at its own speed, Student t across seeds; the "
        "Wilson interval shifted for one policy); – where the world has no frontier here "
        "(the paper's CARLA). ± is the standard deviation across seeds. The authors' speed is "
        "the mean over the steps faster than 0.5 km/h (carla-gym tester.py); a pedestrian "
        "striking the standing car is not a collision (struck while stopped). Env steps / "
        "seed: the mean of what each seed trained on, in millions; – for a policy not "
        "learned here and in tables computed before they were counted. Train wall / seed: "
        "the mean training wall time of a seed, compile and checkpoints included (seeds "
        "trained together share their call's; k of n: over the seeds that counted it); "
        "device: how many seeds trained on which device (? for runs from before devices "
        "were kept).",
    ]
    if legend:
        lines += ["", "Devices: " + "; ".join(f"{k} {d}" for d, k in legend.items()) + "."]
    return "\n".join(lines)
