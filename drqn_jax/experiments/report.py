"""One machine-readable results file, and the documents that quote it: ``study --results FILE
--section NAME`` stores a table's rows (:func:`write_results`); ``drqn-jax report FILE.md`` fills
each ``<!-- results:NAME FORM -->…<!-- /results -->`` block from it (``--check``: fail where they
disagree). FORM: none (all tables), ``legend`` (plus column definitions), ``safety`` (the safety
and speed table), ``table`` (it without verdicts: margins say them), ``brief`` (headline table),
``return`` (safety, speed and return)."""

import json
import math
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drqn_jax.config import ConfigError
from drqn_jax.experiments.checkpoint import atomic_write_text
from drqn_jax.experiments.machine import NOT_RECORDED

#: A section's name: letters, digits, '_', '.' and '-'.
SECTION_NAME = re.compile(r"[\w.-]+")
#: The forms of a generated block (module docstring); "" is the default.
FORMS = ("", "legend", "safety", "table", "brief", "return")
#: A generated block of a document: its section name, its form and its current body.
BLOCK = re.compile(
    rf"(?P<open><!-- results:(?P<section>{SECTION_NAME.pattern})(?: (?P<form>\w+))? -->\n)"
    r"(?P<body>.*?)(?P<close><!-- /results -->)",
    re.S,
)
#: Where a brief block (a README's) points for the columns' definitions.
DEFINITIONS = "[docs/results.md](docs/results.md)"
#: How the verdicts on the paper's claim and on the goal begin (a brief block quotes them).
CLAIM = "The paper's claim"
GOAL = "Table III at scale's goal"


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
    """ConfigError unless ``section`` is a valid section name (:data:`SECTION_NAME`)."""
    if not SECTION_NAME.fullmatch(section):
        raise ConfigError(f"--section {section!r}: must be letters, digits, '_', '.' or '-'")


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
    """Replace ``section``'s rows (and its ``about``, ``comparisons``) in the results file at
    ``path``; other sections stay. Returns the whole record written."""
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


def note_progress(
    path: str | Path, section: str, finished: Mapping[str, int], command: str, store: str
) -> None:
    """Mark ``section`` in progress: runs ``finished`` per arm, the ``command`` that continues
    it and the runs ``store``; an existing table stays until replaced."""
    check_section(section)
    record = load_results(path)
    if "wall_time_s" in record["sections"].get(section, {}):
        return
    progress = {"command": command, "runs_finished": dict(finished), "runs_store": store}
    record["sections"][section] = progress
    _save_record(path, record)


def render_section(record: Mapping[str, Any], section: str, form: str = "") -> str:
    """Markdown of one section in ``form`` (:data:`FORMS`, module docstring)."""
    if form not in FORMS:
        raise ValueError(
            f"results block {section} {form}: the form must be one of {', '.join(FORMS[1:])}"
        )
    if section not in record["sections"]:
        known = ", ".join(record["sections"]) or "none"
        raise ValueError(f"results section {section!r}: not in the results file (has: {known})")
    about = record["sections"][section]
    command = ["", "```bash", about["command"], "```"]
    if "wall_time_s" not in about:  # interrupted before its table: what has finished
        counts = ", ".join(f"`{arm}` {n}" for arm, n in about["runs_finished"].items()) or "none"
        lines = [
            f"**In progress**: no table until every run has finished. Runs finished so far: "
            f"{counts}. The same command continues it, in a fresh clone too (the finished "
            f"runs are kept in `{about['runs_store']}`):",
            *command,
        ]
        return "\n".join(lines) + "\n"
    rows = [r for r in record["rows"] if r.get("section") == section]
    if form == "brief":
        return _brief(rows, about["comparisons"])
    forms = {"safety": TABLES[:1], "table": TABLES[:1], "return": (RETURN_TABLE,)}
    tables = forms.get(form, TABLES)
    comparisons = [] if form in ("table", "return") else about["comparisons"]
    lines = [study_table(rows, comparisons, legend=False, tables=tables)]
    machine = about["machine"]
    went_on = "; earlier invocations trained its runs, the wall time is the last one's"
    lines += [
        "",
        f"Command (wall time {about['wall_time_s'] / 60:.0f} min on {machine.get('usable_cores')} "
        f"cores of {machine.get('cpu_model')}, JAX {machine.get('jax_version')}, "
        f"commit {machine.get('git_commit')}{went_on if about.get('continued') else ''}):",
        *command,
    ]
    if form == "legend":
        lines += ["", column_legend()]
    return "\n".join(lines) + "\n"


def _brief(rows: Sequence[Mapping[str, Any]], comparisons: Sequence[str]) -> str:
    """A section's headline table (:data:`BRIEF`), its verdicts and a legend pointer."""
    verdicts = [f"* {c}" for c in comparisons if c.startswith((CLAIM, GOAL))]
    lines = [_markdown_table(BRIEF, rows, {}), "", *verdicts, *([""] if verdicts else [])]
    lines.append(
        f"Every column is defined, and every row shown in full with its command, in {DEFINITIONS}."
    )
    return "\n".join(lines) + "\n"


def update_document(text: str, record: Mapping[str, Any]) -> str:
    """``text`` with every ``results:NAME [FORM]`` block regenerated from ``record``."""

    def filled(match: re.Match[str]) -> str:
        body = render_section(record, match["section"], match["form"] or "")
        return match["open"] + body + match["close"]

    return BLOCK.sub(filled, text)


#: The paper's Table III: agent, collision-free episodes of 10, avg speed (km/h), distance (m).
PAPER_TABLE_III = (("rule-based", 4, 7.79, 82.6), ("DRQN", 7, 6.09, 123.1))
PAPER_EPISODES = 10
#: The world column of the paper's rows.
PAPER_WORLD = "CARLA (paper)"
#: km/h: the paper's DRQN's average speed (Table III), the claim's threshold (SPEC §9).
PAPER_DRQN_SPEED_KMH = PAPER_TABLE_III[1][2]


def _cell(value: float | None, spec: str, scale: float = 1.0, suffix: str = "") -> str:
    """``value`` × ``scale`` formatted, then ``suffix``; – for None or non-finite."""
    if value is None or not math.isfinite(value):
        return "–"
    return format(scale * value, spec) + suffix


def margin_cell(row: Mapping[str, Any]) -> str:
    """``+5.2 (+1.0 to +9.4)``: the frontier margin in points; – or "– (above the speed
    limit)" without one (SPEC §9)."""
    if row.get("above_speed_limit"):
        return "– (above the speed limit)"
    margin, interval = row.get("frontier_margin"), row.get("frontier_margin_ci")
    if margin is None or not math.isfinite(margin) or interval is None:
        return "–"
    return f"{100 * margin:+.1f} {points_interval(*interval)}"


def points_interval(low: float | None, high: float | None) -> str:
    """``(+1.0 to +9.4)``: an interval of rates in signed points (nan where not finite)."""
    low, high = (100 * x if x is not None and math.isfinite(x) else math.nan for x in (low, high))
    return f"({low:+.1f} to {high:+.1f})"


Cell = Callable[[Mapping[str, Any], Mapping[str, str]], str]


def _metric(key: str, spec: str, scale: float = 1.0, suffix: str = "") -> Cell:
    """The cell of metric ``key`` of a row (– where it has none)."""
    return lambda row, devices: _cell(row.get(key), spec, scale, suffix)


def _seeds(row: Mapping[str, Any], devices: Mapping[str, str]) -> str:
    """``5 × 1000``, then ``(2 diverged)`` where seeds diverged."""
    diverged = f" ({row['diverged']} diverged)" if row["diverged"] else ""
    return f"{row['seeds']} × {row['episodes']}{diverged}"


def _free(row: Mapping[str, Any], devices: Mapping[str, str]) -> str:
    """``60.0 (57.0–63.0)``: the collision-free rate and its interval, in %."""
    low, high = row["collision_free_ci"]
    return f"{100 * row['collision_free_rate']:.1f} ({100 * low:.1f}–{100 * high:.1f})"


def _speed(row: Mapping[str, Any], devices: Mapping[str, str]) -> str:
    """``6.09 ± 0.31``: the mean speed, ± its standard deviation across seeds where known."""
    std = _cell(row["avg_speed_kmh_std"], ".2f")
    return _cell(row["avg_speed_kmh"], ".2f") + ("" if std == "–" else f" ± {std}")


def _wall(row: Mapping[str, Any], devices: Mapping[str, str]) -> str:
    """``31.2`` mean training minutes per seed; ``31.2 (2 of 5)`` if partial; – for none."""
    cell = _cell(row.get("train_wall_s_per_seed"), ".1f", 1 / 60)
    counted = row.get("train_wall_seeds")
    if cell != "–" and counted is not None and counted < row["seeds"]:
        cell += f" ({counted} of {row['seeds']})"
    return cell


def _device(row: Mapping[str, Any], devices: Mapping[str, str]) -> str:
    """``[1] ×3, [2] ×2``: how many seeds trained on each device; – for none."""
    counts = row.get("devices") or {}
    return ", ".join(f"{devices.get(d, '?')} ×{n}" for d, n in counts.items()) or "–"


#: Every column of the results tables: header → (right-aligned, ``cell(row, devices)``).
COLUMNS: dict[str, tuple[bool, Cell]] = {
    "source": (False, lambda row, devices: row["label"]),
    "agent": (False, lambda row, devices: row["agent"]),
    "teacher": (False, lambda row, devices: row["learned"]),
    "seeds × episodes": (True, _seeds),
    "collision-free % (95 % interval)": (False, _free),
    "margin to the rule-based frontier, points (95 %)": (False, lambda row, _: margin_cell(row)),
    "struck while stopped %": (True, _metric("struck_while_stopped_rate", ".1f", 100.0)),
    "avg speed (km/h)": (True, _speed),
    "authors' speed (km/h)": (True, _metric("avg_speed_authors_kmh", ".2f")),
    "distance (m)": (True, _metric("avg_distance_m", ".1f")),
    "distance, collision-free (m)": (True, _metric("avg_distance_collision_free_m", ".1f")),
    "goal %": (True, _metric("goal_rate", ".1f", 100.0)),
    "collisions / km": (True, _metric("collisions_per_km", ".2f")),
    "ticks / decision": (True, _metric("decision_steps", ".0f")),
    "decisions / seed": (True, _metric("env_steps_per_seed", ".2f", 1e-6, "M")),
    "ticks / seed": (True, _metric("ticks_per_seed", ".2f", 1e-6, "M")),
    "train wall / seed (min)": (True, _wall),
    "device": (False, _device),
    "return / episode": (True, _metric("avg_return", ".0f")),
}
#: What each column means (:func:`column_legend`): ``header: definition``, continued on
#: indented lines, in the order of :data:`COLUMNS`.
LEGEND = """\
source: the paper's Table III (CARLA, 10 episodes), or `drqn_jax:` a config trained here (`on ENV`:
  its agents evaluated among another env's pedestrians), a world's rule-based agent (its env id),
  or a setting of the rule-based frontier or the privileged planner; after `;`: the reward scored
agent: the learner and its network (`drqn`, `dqn`, `pqn` and `ppo` recurrent, `pqn-ff` and `ppo-ff`
  feed-forward) or a policy not learned (`rule-based`, `planner`)
teacher: what the agent learned from besides the reward: none, guided exploration or imitation of
  the rule-based agent; – for a policy not learned
seeds × episodes: training seeds (1 for a single policy) × greedy evaluation episodes of each,
  every agent of a section on the same episodes; diverged: seeds whose loss went non-finite
collision-free % (95 % interval): episodes without a collision; the interval is the 95 % Student t
  of the mean across seeds for a trained config (training and episodes vary; cut to 0–100 %),
  Wilson over the episodes for one policy (the rule-based agent, the paper's rows)
margin to the rule-based frontier, points (95 %): the collision-free rate minus the rule-based
  family's frontier at the agent's own average speed (SPEC §9; each seed at its own speed,
  Student t across seeds; the Wilson interval shifted for one policy); – where the world has no
  frontier here (the paper's CARLA) or the agent drives faster than the speed limit
struck while stopped %: episodes in which a pedestrian met the collision test while the car stood
  (not counted as a collision)
avg speed (km/h): the mean over episodes of distance over time; ± is the standard deviation across
  seeds
authors' speed (km/h): the authors' average speed: the mean over every step faster than 0.5 km/h
  (carla-gym tester.py, SPEC §8)
distance (m): the mean distance driven
distance, collision-free (m): the mean distance of the collision-free episodes, pooled over seeds
goal %: episodes that reach the goal
collisions / km: all collisions over all distance driven, pooled over seeds
ticks / decision: how many 0.1 s ticks each action holds (env.decision_steps; the rule-based
  agent and the planner decide every tick)
decisions / seed: the mean of the decisions (env steps) each seed trained on, in millions; – where
  not counted
ticks / seed: decisions × ticks / decision, in millions: the simulated driving each seed trained on
train wall / seed (min): the mean training wall time of a seed, compile and checkpoints included
  (seeds trained together share their call's); k of n: over the seeds that counted it
device: how many seeds trained on each device, numbered as the line under the tables names them;
  ? where a run's device was not recorded
return / episode: the mean sum of an episode's rewards under the row's reward, what a learner of it
  maximizes
"""
_HEADERS = tuple(COLUMNS)
_KEYS = _HEADERS[:4]
#: A section's tables: caption, identifying columns, shown columns (all-– rows left out).
TABLES = (
    ("Safety and speed", _KEYS, _HEADERS[4:8]),
    ("Driving", _KEYS[:2], _HEADERS[8:13]),
    ("Training", (*_KEYS[:2], _KEYS[3]), _HEADERS[13:-1]),
)
#: The ``return`` form's table: safety, speed and the return under the row's reward.
RETURN_TABLE = ("Return", _KEYS[:2], (*_HEADERS[4:6], "avg speed (km/h)", "return / episode"))
#: The headline table's columns (a brief block's, :func:`render_section`).
BRIEF = (*_KEYS, "ticks / seed", *_HEADERS[4:6], "avg speed (km/h)")


def _markdown_table(
    headers: Sequence[str], rows: Sequence[Mapping[str, Any]], devices: Mapping[str, str]
) -> str:
    """The ``headers`` columns (:data:`COLUMNS`) of ``rows`` as a Markdown table."""
    columns = [COLUMNS[h] for h in headers]
    lines = ["| " + " | ".join(headers) + " |"]
    lines.append("| " + " | ".join("---:" if right else "---" for right, _ in columns) + " |")
    lines += ["| " + " | ".join(cell(r, devices) for _, cell in columns) + " |" for r in rows]
    return "\n".join(lines)


def study_table(
    rows: Sequence[Mapping[str, Any]],
    notes: Sequence[str] = (),
    legend: bool = True,
    tables: Sequence[tuple[str, tuple[str, ...], tuple[str, ...]]] = TABLES,
) -> str:
    """Markdown of ``rows`` as ``tables`` (default :data:`TABLES`; captioned when more than
    one is shown), device legend, ``notes`` and, with ``legend``, every column's definition."""
    names = dict.fromkeys(d for r in rows for d in r.get("devices") or {} if d != NOT_RECORDED)
    devices = {d: f"[{k}]" for k, d in enumerate(names, 1)}  # device → [k], in order first seen
    parts = []
    for caption, keys, shown in tables:
        kept = [r for r in rows if any(COLUMNS[h][1](r, devices) != "–" for h in shown)]
        if kept:
            parts += [f"{caption}:", _markdown_table((*keys, *shown), kept, devices)]
    if len(parts) == 2:  # one table: no caption
        parts = parts[1:]
    if devices and any(caption == "Training" for caption, _, _ in tables):
        parts.append("Devices: " + "; ".join(f"{k} {d}" for d, k in devices.items()) + ".")
    if notes:
        parts.append("\n".join(f"* {note}" for note in notes))
    if legend:
        parts.append(column_legend())
    return "\n\n".join(parts)


def column_legend() -> str:
    """Markdown: what every column of the results tables (:data:`COLUMNS`) means."""
    entries = (line.split(": ", 1) for line in LEGEND.replace("\n  ", " ").splitlines())
    definitions = [f"* **{header}**: {text}." for header, text in entries]
    lead = "The columns (a table leaves out a row whose cells in it would all be –):"
    return "\n\n".join([lead, "\n".join(definitions)])
