"""Calibration of the paper's world: the rule-based agent in each candidate world.

Usage::

    python -m benchmarks.calibrate_world [--episodes 1000] [--out docs/calibration.json]

The paper's rule-based agent was collision-free in 4 of 10 episodes (40 %,
Wilson 95 % interval 16.8-68.7 %) at 7.79 km/h (Table III). Each candidate
world below changes only settings with evidence behind them (docs/spec.md §3,
§5): how pedestrians behave toward the car and the collision test; the yield
timeout is CARLA's 5 s, and one row keeps pedestrians that wait for ever,
for reference. Every row evaluates SPEC §6's rule-based agent on the same
``--episodes`` episodes of seed 0's evaluation key, exactly what
``drqn-jax evaluate --agent rule-based --set ...`` prints for that world.

Writes ``--out`` (JSON: the rows, the paper's numbers, the machine and the
command) and renders the table into ``docs/spec.md`` between its
``<!-- calibration table -->`` markers, so the document reads the numbers
from the file and never retypes them.
"""

import argparse
import json
import math
import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from drqn_jax.config import load_config
from drqn_jax.evaluation import wilson_interval
from drqn_jax.experiments.machine import machine_info
from drqn_jax.experiments.runner import builtin_agent, evaluate_agents

ROOT = Path(__file__).resolve().parent.parent
SPEC_DOC = ROOT / "docs" / "spec.md"
MARKER = "<!-- calibration table -->"
END_MARKER = "<!-- /calibration table -->"

#: The paper's rule-based agent (Table III): collision-free episodes of 10, km/h, m.
PAPER = {"collision_free": 4, "episodes": 10, "avg_speed_kmh": 7.79, "avg_distance_m": 82.6}

#: (name, --set overrides, what the evidence says). The first row is the default world.
CANDIDATES: tuple[tuple[str, tuple[str, ...], str], ...] = (
    (
        "ignore, authors",
        ("env.ped_behaviour_to_car=ignore", "env.collision_model=authors"),
        "the authors' walkers and the authors' collision test",
    ),
    (
        "ignore, contact",
        ("env.ped_behaviour_to_car=ignore", "env.collision_model=contact"),
        "the authors' walkers, the project's box-disc contact",
    ),
    (
        "yield 5 s, authors",
        ("env.ped_behaviour_to_car=yield", "env.collision_model=authors"),
        "stock CARLA walkers (wait 5 s, then walk on), the authors' test",
    ),
    (
        "yield 5 s, contact",
        ("env.ped_behaviour_to_car=yield", "env.collision_model=contact"),
        "stock CARLA walkers, contact (UrbanPedestriansYielding-v0)",
    ),
    (
        "yield for ever, contact",
        (
            "env.ped_behaviour_to_car=yield",
            "env.collision_model=contact",
            "env.ped_wait_max_s=1000",
        ),
        "pedestrians that wait for ever, with standoffs (reference only)",
    ),
)

_KEYS = (
    "collision_free_rate",
    "collision_free_ci",
    "struck_while_stopped_rate",
    "goal_rate",
    "avg_speed_kmh",
    "avg_speed_authors_kmh",
    "avg_distance_m",
)


def paper_likelihood(rate: float) -> float:
    """Binomial probability of the paper's 4 collision-free episodes of 10 at ``rate``."""
    k, n = PAPER["collision_free"], PAPER["episodes"]
    return math.comb(n, k) * rate**k * (1.0 - rate) ** (n - k)


def calibrate(episodes: int) -> list[dict[str, Any]]:
    """One row per candidate world: the rule-based agent's SPEC §8 metrics."""
    rows = []
    for name, overrides, evidence in CANDIDATES:
        config = load_config(None, [*overrides, f"evaluate.episodes={episodes}"])
        (result,) = evaluate_agents(config, [builtin_agent("rule-based", config)])
        row = {"world": name, "set": list(overrides), "evidence": evidence}
        row.update({k: result[k] for k in _KEYS})
        row["paper_likelihood"] = paper_likelihood(result["collision_free_rate"])
        rows.append(row)
    return rows


def markdown(data: dict[str, Any]) -> str:
    """The calibration table (and the command that made it) as Markdown."""
    low, high = wilson_interval(PAPER["collision_free"], PAPER["episodes"])
    lines = [
        f"Rule-based agent (SPEC §6) over {data['episodes']} episodes of seed 0's evaluation "
        f"key; the paper: {100 * PAPER['collision_free'] / PAPER['episodes']:.0f} % "
        f"({100 * low:.1f}–{100 * high:.1f}) at {PAPER['avg_speed_kmh']} km/h, "
        f'{PAPER["avg_distance_m"]} m. "P(4/10)" is the probability of the paper\'s 4 '
        "collision-free episodes of 10 if the world's rate were the measured one.",
        "",
        "| world (`--set`) | collision-free % (95 % CI) | struck while stopped % | goal % "
        "| avg speed (km/h) | authors' speed (km/h) | distance (m) | P(4/10) | evidence |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in data["rows"]:
        lo, hi = r["collision_free_ci"]
        sets = " ".join(f"`{s}`" for s in r["set"])
        lines.append(
            f"| {r['world']} ({sets}) | {100 * r['collision_free_rate']:.1f} "
            f"({100 * lo:.1f}–{100 * hi:.1f}) | {100 * r['struck_while_stopped_rate']:.1f} "
            f"| {100 * r['goal_rate']:.1f} | {r['avg_speed_kmh']:.2f} "
            f"| {r['avg_speed_authors_kmh']:.2f} | {r['avg_distance_m']:.1f} "
            f"| {r['paper_likelihood']:.3f} | {r['evidence']} |"
        )
    lines += [
        "",
        f"Command: `{data['command']}` ({data['wall_s']:.0f} s on "
        f"{data['machine']['cpu_model']}, JAX {data['machine']['jax_version']}, commit "
        f"{data['machine']['git_commit']}; the file `docs/calibration.json` holds every number).",
    ]
    return "\n".join(lines)


def render_into(doc: Path, table: str) -> None:
    """Replace what stands between the calibration markers of ``doc`` by ``table``."""
    text = doc.read_text()
    if MARKER not in text:
        raise SystemExit(f"{doc} has no '{MARKER}' line")
    block = f"{MARKER}\n{table}\n{END_MARKER}"
    pattern = re.escape(MARKER) + r"(.*?" + re.escape(END_MARKER) + r")?"
    doc.write_text(re.sub(pattern, lambda _: block, text, count=1, flags=re.S))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.calibrate_world")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "calibration.json")
    parser.add_argument("--doc", type=Path, default=SPEC_DOC, help="Markdown file to render into")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = calibrate(args.episodes)
    info = machine_info()
    data = {
        "command": f"python -m benchmarks.calibrate_world --episodes {args.episodes}",
        "episodes": args.episodes,
        "paper": PAPER,
        "rows": rows,
        "wall_s": time.perf_counter() - start,
        "machine": info,
    }
    args.out.write_text(json.dumps(data, indent=2) + "\n")
    render_into(args.doc, markdown(data))
    print(markdown(data))


if __name__ == "__main__":
    main()
