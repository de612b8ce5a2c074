"""The agents shipped with the package: each loads with this version (its checkpoint
format and training hash), and its provenance names a command that trains exactly its
config and what trained it."""

from __future__ import annotations

import json
import shlex

import pytest

from drqn_jax.agents.shipped import shipped_agent_dir, shipped_agents
from drqn_jax.config import load_config
from drqn_jax.experiments.runner import load_run, load_trained_network


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
