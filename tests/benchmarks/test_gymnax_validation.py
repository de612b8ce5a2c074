"""The learner on environments nobody here wrote (gymnax), fast versions of
``benchmarks/gymnax_validation.py``: the DQN learns CartPole-v1, and on
bsuite's MemoryChain the DRQN remembers where the memoryless DQN cannot."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.gymnax_validation import RECIPES, cartpole_config, memory_config, run_recipe
from drqn_jax.task import make_task
from drqn_jax.train import make_train

SEEDS = 2


def test_gymnax_task_steps_as_the_contract_says():
    """A gymnax env as a task: flat float observations (an image flattened), the
    MLP torso sized from them, the pre-reset observation of an ended episode as
    its final record, and no teacher (guided exploration is refused in one line)."""
    task = make_task("gymnax:CartPole-v1")
    assert task.num_actions == 2 and task.max_steps == 500 and task.teacher is None
    net = task.network(cartpole_config().network)
    assert (net.torso, net.obs_size, net.num_actions) == ("mlp", 4, 2)
    _, state = task.reset(jax.random.key(0), task.env_params)
    ended = None
    for i in range(200):  # always push right: the pole falls within 200 steps
        step = task.step(jax.random.key(i), state, jnp.int32(1), task.env_params)
        if bool(step.terminated):
            ended = step
            break
        state = step.state
    assert ended is not None and not bool(ended.truncated)
    assert not np.array_equal(np.asarray(ended.final), np.asarray(ended.obs))  # reset after
    minatar = make_task("gymnax:Breakout-MinAtar")  # a (10, 10, 4) observation, flattened
    obs, _ = minatar.reset(jax.random.key(0), minatar.env_params)
    assert minatar.record.shape == obs.shape == (400,)
    assert minatar.network(cartpole_config().network).obs_size == 400
    bad = cartpole_config()
    bad = dataclasses.replace(bad, hyperparams=bad.hyperparams.replace(explore_guide=0.5))
    with pytest.raises(
        ValueError, match=r"explore_guide = 0\.5: gymnax:CartPole-v1 has no teacher"
    ):
        make_train(bad)


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
    alone (a dropped field once made the two rows the same run)."""
    configs = {name: make() for name, (make, _, _) in RECIPES.items()}
    drqn, dqn = configs["memory-drqn"], configs["memory-dqn"]
    assert dataclasses.replace(dqn, network=drqn.network) == drqn
    zero, stored = configs["memory12-drqn"], configs["memory12-drqn-stored"]
    assert (zero.stored_state, stored.stored_state) == (0, 1)
    assert dataclasses.replace(stored, stored_state=0) == zero
