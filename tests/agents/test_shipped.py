"""The agents shipped with the package: each loads with this version (its checkpoint
format and training hash), and its provenance names a command that trains exactly its
config and what trained it."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import pytest

from drqn_jax.agents import drqn_agent
from drqn_jax.agents.shipped import shipped_agent_dir, shipped_agents
from drqn_jax.config import load_config
from drqn_jax.experiments.report import load_results
from drqn_jax.experiments.runner import evaluate_agents, load_run, load_trained_network


def _trained_config(command: str):
    """The config that ``drqn-jax train --config NAME --set …`` trains."""
    words = shlex.split(command)
    assert words[:2] == ["drqn-jax", "train"], command
    name = words[words.index("--config") + 1]
    sets = [words[i + 1] for i, w in enumerate(words) if w == "--set"]
    return load_config(name, sets)


@pytest.mark.parametrize("name", shipped_agents())
def test_a_shipped_agent_loads_and_its_command_trains_its_config(name):
    directory = shipped_agent_dir(name)
    config = load_run(directory)
    _, _, meta = load_trained_network(config, directory)  # checks the training hash
    provenance = json.loads((directory / "provenance.json").read_text())
    assert meta["finished"] and provenance["env_steps"] == meta["env_steps"] > 0
    assert _trained_config(provenance["command"]).training_hash() == config.training_hash()
    assert provenance["machine"]["git_commit"] and provenance["machine"]["cpu_model"]
    assert provenance["trained"]["commit"] and provenance["trained"]["device"]
    assert (directory / "agent.npz").stat().st_size < 5_000_000  # a few MB in git


def test_the_headline_is_shipped_and_unknown_names_are_refused():
    assert "headline" in shipped_agents()
    with pytest.raises(ValueError, match=r"no shipped agent 'nope' \(shipped: headline\)"):
        shipped_agent_dir("nope")


def test_the_headline_reproduces_its_seed_of_table_three():
    """``drqn-jax evaluate --agent headline`` on its config's 1000 evaluation episodes gives
    seed 0 of Table III at scale's `pqn` row: the same collision-free episodes, the speed
    to float32 rounding (exact on the CPU model that evaluated it)."""
    directory = shipped_agent_dir("headline")
    config = load_run(directory)
    network, weights, _ = load_trained_network(config, directory)
    (result,) = evaluate_agents(config, [drqn_agent(network, weights)])
    record = load_results(Path(__file__).resolve().parents[2] / "docs" / "results.json")
    (row,) = [
        r
        for r in record["rows"]
        if r["section"] == "table3-cpu-k5" and r["label"] == "drqn_jax: pqn"
    ]
    seed = row["per_seed"][0]
    assert result["num_episodes"] == config["evaluate"]["episodes"] == 1000
    assert result["collision_free_rate"] == seed["collision_free_rate"]
    assert result["avg_speed_kmh"] == pytest.approx(seed["avg_speed_kmh"], rel=1e-6)
