"""The default rule-based settings of the frontier, from a wide sweep (SPEC §9).

Usage::

    drqn-jax frontier --wide --no-planner --no-png --out runs/frontier-wide   # 6 min on an H100
    python -m benchmarks.frontier_settings runs/frontier-wide/frontier.json [--keep 30]

A frontier sweep must be cheap (it runs in every study, for every world) and
strong (no rule-based setting a reviewer tries should beat it). The wide sweep
(``drqn_jax.experiments.frontier.WIDE_GRID``) evaluates 3000 settings; this script keeps its
Pareto-efficient ones and the paper's, and drops, one at a time, the setting whose
loss moves the Pareto curve (linear between its points) least, never a vertex of the envelope
(the frontier margins read), the fastest setting or the paper's, until ``--keep``
remain. It prints them as ``drqn_jax.experiments.frontier._SETTINGS`` holds them, with the
largest gap left between the thinned and the full Pareto curve, and whether the
two envelopes are the same.
"""

import argparse
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drqn_jax.experiments.frontier import frontier_vertices, pareto_points

AXES = ("v_max_kmh", "lookahead", "horizon", "corridor_margin")
#: The paper's rule-based agent (SPEC §6): always kept.
PAPER = {"v_max_kmh": 15.0, "lookahead": 7.0, "horizon": 0.0, "corridor_margin": 0.5}


def _curve(points: Sequence[Mapping[str, Any]], speeds: np.ndarray) -> np.ndarray:
    """The Pareto curve of ``points``, linear between its points, at ``speeds``."""
    points = pareto_points(points)
    xs = [p["avg_speed_kmh"] for p in points]
    return np.interp(speeds, xs, [p["collision_free_rate"] for p in points])


def thin(points: Sequence[Mapping[str, Any]], keep: int) -> tuple[list[Mapping[str, Any]], float]:
    """The Pareto points of ``points`` thinned to ``keep`` (module docstring), and the
    largest gap (rate) between their curve and the full Pareto curve."""
    pareto = pareto_points(points)
    paper = [p for p in points if dict(p["params"]) == PAPER and p not in pareto]
    vertices = set(frontier_vertices(points))
    top = max(p["avg_speed_kmh"] for p in pareto)
    speeds = np.linspace(0.0, top, 1001)
    full = _curve(pareto, speeds)

    def fixed(p: Mapping[str, Any]) -> bool:
        on_envelope = (p["avg_speed_kmh"], p["collision_free_rate"]) in vertices
        return on_envelope or p["avg_speed_kmh"] == top or dict(p["params"]) == PAPER

    kept = sorted([*pareto, *paper], key=lambda p: p["avg_speed_kmh"])
    while len(kept) > keep:
        gaps = [
            (float(np.abs(full - _curve(kept[:i] + kept[i + 1 :], speeds)).max()), i)
            for i, p in enumerate(kept)
            if not fixed(p)
        ]
        if not gaps:
            break
        kept.pop(min(gaps)[1])
    return kept, float(np.abs(full - _curve(kept, speeds)).max())


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("frontier_json", help="OUT/frontier.json of drqn-jax frontier --wide")
    parser.add_argument("--keep", type=int, default=30, help="settings to keep")
    args = parser.parse_args(argv)
    record = json.loads(Path(args.frontier_json).read_text())
    points = record["rule_based"]["swept_points"]
    kept, gap = thin(points, args.keep)
    same = frontier_vertices(kept) == frontier_vertices(points)
    print(
        f"# {len(kept)} of {len(points)} settings ({len(pareto_points(points))} Pareto-efficient)"
    )
    print(f"# largest gap to the full Pareto curve: {100 * gap:.2f} points; same envelope: {same}")
    for p in kept:
        print("    (" + ", ".join(repr(float(p["params"][a])) for a in AXES) + "),")


if __name__ == "__main__":
    main()
