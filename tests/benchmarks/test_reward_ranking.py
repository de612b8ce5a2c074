"""``benchmarks.reward_ranking`` at a tiny size: each agent on the same episodes under each
reward drives the same and earns a different return, the section stores it with margins, and
the ``return`` form of a results block shows it; without a stored frontier it is refused."""

import json

import pytest

from benchmarks import reward_ranking
from drqn_jax.config import load_config
from drqn_jax.experiments.baselines import frontier_key
from drqn_jax.experiments.report import load_results, render_section
from tests.helpers import HAND_FRONTIER


def test_a_reward_changes_the_return_not_the_driving(tmp_path, monkeypatch):
    monkeypatch.setattr(reward_ranking, "AGENTS", {"rule-based": "--agent rule-based"})
    paper = "--set env.reward_collision=-10 --set env.reward_stopped=-1"
    monkeypatch.setattr(reward_ranking, "REWARDS", {"default's": "", "paper's": paper})
    results = tmp_path / "results.json"
    config = load_config("default", ["evaluate.episodes=2"])
    frontiers = {frontier_key(config): HAND_FRONTIER}
    results.write_text(json.dumps({"rows": [], "sections": {"f": {"frontiers": frontiers}}}))

    reward_ranking.main(["--episodes", "2", "--results", str(results)])
    rows = [r for r in load_results(results)["rows"] if r["section"] == "reward-ranking"]
    assert [r["label"] for r in rows] == ["rule-based; default's", "rule-based; paper's"]
    default, paper = rows
    for key in ("collision_free_rate", "avg_speed_kmh", "avg_distance_m", "frontier_margin"):
        assert default[key] == paper[key] is not None, key
    assert paper["avg_return"] != default["avg_return"]
    assert load_results(results)["sections"]["reward-ranking"]["frontiers"] == frontiers
    block = render_section(load_results(results), "reward-ranking", "return")
    header = block.splitlines()[0]
    assert header.endswith("| avg speed (km/h) | return / episode |")
    assert f"| {round(default['avg_return'])} |" in block


def test_without_a_stored_frontier_it_is_refused_before_evaluating(tmp_path):
    results = tmp_path / "results.json"
    results.write_text(json.dumps({"rows": [], "sections": {}}))
    with pytest.raises(SystemExit) as refused:
        reward_ranking.main(["--episodes", "2", "--results", str(results)])
    assert refused.value.code == 2
