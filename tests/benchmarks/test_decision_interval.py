"""``benchmarks.decision_interval`` at tiny sizes: arms at k ticks per decision on one
budget of ticks, their rows and curves stored, a second call trains nothing, more seeds
confirm an arm."""

from __future__ import annotations

import json

import pytest

from benchmarks import decision_interval
from drqn_jax.config import load_config
from drqn_jax.experiments.baselines import frontier_key
from tests.helpers import HAND_FRONTIER

TINY = [
    "train.algorithm=pqn",
    "train.num_envs=4",
    "train.rollout_steps=8",
    "train.num_minibatches=2",
    "train.chunk_iterations=1",
    "network.layer_norm=true",
]


def _args(results, *extra):
    sets = [x for s in TINY for x in ("--set", s)]
    return ["--configs", "smoke", "--ticks", "64", "--points", "1", "--episodes", "4",
            "--results", str(results), *sets, *extra]  # fmt: skip


def test_each_arm_trains_ticks_over_k_decisions_and_is_stored_once(tmp_path, capsys):
    config = load_config("smoke", [*TINY, "evaluate.episodes=4"])
    results = tmp_path / "results.json"
    frontiers = {frontier_key(config): HAND_FRONTIER}
    earlier = {"frontiers": {"earlier": HAND_FRONTIER}}  # a frontier an earlier row used
    sections = {"f": {"frontiers": frontiers}, "decision-interval": earlier}
    results.write_text(json.dumps({"rows": [], "sections": sections}))

    decision_interval.main(_args(results, "--k", "1,2"))
    record = json.loads(results.read_text())
    rows = [r for r in record["rows"] if r["section"] == "decision-interval"]
    assert [(r["decision_steps"], r["label"]) for r in rows] == [
        (1, "drqn_jax: smoke, k = 1, " + ", ".join(TINY)),
        (2, "drqn_jax: smoke, k = 2, " + ", ".join(TINY)),
    ]
    section = record["sections"]["decision-interval"]
    assert set(section["frontiers"]) == {"earlier", frontier_key(config)}
    curves = section["curves"]
    for row in rows:
        (point,) = curves[row["label"] + ", seed 0"]
        k = row["decision_steps"]
        assert point["ticks"] == k * point["env_steps"] == row["ticks_per_seed"]
        assert point["env_steps"] >= 64 // k  # the budget in ticks, reached at a chunk's end
        assert row["frontier_margin"] is not None and row["episodes"] == 4
        assert row["learned"] == "none (reward alone)"

    capsys.readouterr()
    decision_interval.main(_args(results, "--k", "1,2"))
    assert "decisions" not in capsys.readouterr().out  # nothing trained again
    assert json.loads(results.read_text())["rows"] == record["rows"]


def test_an_arm_without_a_stored_frontier_is_refused(tmp_path):
    results = tmp_path / "results.json"
    results.write_text(json.dumps({"rows": [], "sections": {}}))
    with pytest.raises(SystemExit) as refused:
        decision_interval.main(_args(results, "--k", "1"))
    assert refused.value.code == 2


def test_more_seeds_train_only_the_new_seeds_and_make_one_row(tmp_path, capsys):
    config = load_config("smoke", [*TINY, "evaluate.episodes=4"])
    results = tmp_path / "results.json"
    frontiers = {frontier_key(config): HAND_FRONTIER}
    results.write_text(json.dumps({"rows": [], "sections": {"f": {"frontiers": frontiers}}}))
    decision_interval.main(_args(results, "--k", "2"))
    capsys.readouterr()

    decision_interval.main(_args(results, "--k", "2", "--seeds", "0,1"))
    out = capsys.readouterr().out
    assert "seed 1:" in out and "seed 0:" not in out  # seed 0 is stored
    (row,) = [r for r in json.loads(results.read_text())["rows"] if r.get("decision_steps")]
    assert row["seeds"] == 2 and row["interval"] == "t over seeds"
    assert [s["seed"] for s in row["per_seed"]] == [0, 1]
    # the frontier stays keyed by the episodes it was played on (the config's run.seed)
    section = json.loads(results.read_text())["sections"]["decision-interval"]
    assert list(section["frontiers"]) == [frontier_key(config)]
