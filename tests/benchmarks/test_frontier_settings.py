"""benchmarks/frontier_settings.py: thinning a wide sweep keeps the envelope."""

from __future__ import annotations

import json

from benchmarks.frontier_settings import PAPER, main, thin
from drqn_jax.experiments.frontier import frontier_vertices


def _point(speed: float, rate: float, **params: float) -> dict:
    setting = {"lookahead": 7.0, "horizon": 0.0, "corridor_margin": 1.0, **params}
    return {"avg_speed_kmh": speed, "collision_free_rate": rate, "params": setting}


#: A swept family: the envelope's vertices, Pareto points under it, dominated ones,
#: and the paper's setting (dominated: kept all the same).
SWEPT = [
    _point(0.0, 1.0, v_max_kmh=1.0),
    _point(1.0, 0.9, v_max_kmh=2.0),
    _point(2.0, 0.85, v_max_kmh=3.0),
    _point(3.0, 0.7, v_max_kmh=4.0),
    _point(4.0, 0.6, v_max_kmh=5.0),
    _point(5.0, 0.52, v_max_kmh=6.0),
    _point(6.0, 0.3, v_max_kmh=7.0),
    _point(2.5, 0.5, v_max_kmh=8.0),  # dominated
    _point(5.5, 0.4, **PAPER),  # Pareto-efficient
]


def test_thinning_keeps_the_envelope_and_the_papers_setting():
    kept, gap = thin(SWEPT, keep=5)
    assert len(kept) == 5
    assert frontier_vertices(kept) == frontier_vertices(SWEPT)
    assert any(p["params"] == PAPER for p in kept)
    assert 0.0 < gap < 0.2
    everything, none = thin(SWEPT, keep=100)
    assert len(everything) == 8 and none == 0.0  # the dominated one is never kept


def test_the_script_prints_the_settings(tmp_path, capsys):
    path = tmp_path / "frontier.json"
    path.write_text(json.dumps({"rule_based": {"swept_points": SWEPT}}))
    main([str(path), "--keep", "6"])
    out = capsys.readouterr().out
    assert out.startswith("# 6 of 9 settings (8 Pareto-efficient)")
    assert "same envelope: True" in out and "    (15.0, 7.0, 0.0, 0.5)," in out


def test_a_dominated_papers_setting_is_kept_off_the_curve():
    """The paper's setting is swept even when dominated, and the curve the thinning
    measures is the Pareto points' alone (no dip to the dominated point)."""
    dominated = [*SWEPT[:-1], _point(5.5, 0.2, **PAPER)]
    kept, gap = thin(dominated, keep=5)
    assert any(p["params"] == PAPER for p in kept) and len(kept) == 5
    assert frontier_vertices(kept) == frontier_vertices(dominated)
    assert gap == thin(SWEPT[:-1], keep=4)[1]


def test_the_stored_wide_sweep_gives_the_default_settings(capsys):
    """benchmarks/results/frontier-wide.json (the wide sweep's Pareto points) thinned
    to 30 is drqn_jax.experiments.frontier.RULE_BASED_SETTINGS, in order."""
    from pathlib import Path

    from drqn_jax.experiments.frontier import RULE_BASED_SETTINGS

    stored = Path(__file__).parents[2] / "benchmarks" / "results" / "frontier-wide.json"
    main([str(stored), "--keep", str(len(RULE_BASED_SETTINGS))])
    printed = [line for line in capsys.readouterr().out.splitlines() if line[:5] == "    ("]
    axes = ("v_max_kmh", "lookahead", "horizon", "corridor_margin")
    assert printed == [
        "    (" + ", ".join(repr(float(s[a])) for a in axes) + ")," for s in RULE_BASED_SETTINGS
    ]
