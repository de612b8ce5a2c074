"""``benchmarks/gymnax_validation.py``, fast: the learner on environments nobody here
wrote (gymnax): the DQN learns CartPole-v1, and on bsuite's MemoryChain the DRQN
remembers where the memoryless DQN cannot; the recipes differ only where they say.
(The gymnax env as a task is tested in ``tests/learners/test_task.py``.)"""

from __future__ import annotations

import dataclasses

from benchmarks.gymnax_validation import RECIPES, cartpole_config, memory_config, run_recipe

SEEDS = 2


def test_dqn_learns_cartpole():
    """A CartPole-v1 run of half the benchmark's episodes (about 10⁵ env steps):
    every seed's chosen greedy policy balances far longer than a random one
    (about 22 steps)."""
    out = run_recipe(cartpole_config(num_episodes=1000, snapshots=3), SEEDS, episodes=20)
    assert min(out["mean_return"]) > 100.0, out


def test_drqn_remembers_where_the_dqn_cannot():
    """MemoryChain (memory length 5): the DRQN repeats the first observation's bit
    at the end in >= 90 % of greedy episodes for every seed; the memoryless DQN,
    trained alike, cannot beat chance (at most 70 % for any seed)."""
    drqn = run_recipe(memory_config("drqn", num_episodes=400), SEEDS, episodes=100)
    dqn = run_recipe(memory_config("dqn", num_episodes=400), SEEDS, episodes=100)
    assert min(drqn["success"]) >= 0.9, drqn
    assert max(dqn["success"]) <= 0.7, dqn


def test_memory_recipes_differ_only_where_they_say():
    """The MemoryChain recipes of the benchmark: the DQN differs from the DRQN in
    its kind alone; the stored-state DRQN from the zero-start one in stored_state
    alone (a dropped field once made the two rows the same run); the GRU PQN from
    the wide one in its cell alone."""
    configs = {name: make() for name, (make, _, _) in RECIPES.items()}
    drqn, dqn = configs["memory-drqn"], configs["memory-dqn"]
    assert dataclasses.replace(dqn, network=drqn.network) == drqn
    zero, stored = configs["memory12-drqn"], configs["memory12-drqn-stored"]
    assert (zero.stored_state, stored.stored_state) == (0, 1)
    assert dataclasses.replace(stored, stored_state=0) == zero
    wide, gru = configs["memory100-pqn-wide"], configs["memory100-pqn-gru"]
    assert (wide.network.cell, gru.network.cell) == ("lstm", "gru")
    assert dataclasses.replace(gru, network=wide.network) == wide
