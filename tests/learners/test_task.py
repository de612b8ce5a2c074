"""What the learner needs of an environment (drqn_jax/learners/task.py; SPEC §7): a gymnax
env as a :class:`Task` steps as the contract says, and the gymnax env it wraps keeps
the contract ``drqn_jax.testing.check_env_contract`` checks (with gymnax's reset key)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.gymnax_validation import cartpole_config
from drqn_jax.learners import make_train
from drqn_jax.learners.task import Step, make_task
from drqn_jax.testing import check_env_contract


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


def test_the_wrapped_gymnax_env_keeps_the_contract():
    """CartPole-v1 under the shared checker: gymnax's ``step`` draws the new
    episode from ``split(key)[1]``; random actions drop the pole within 64 steps."""
    task = make_task("gymnax:CartPole-v1")
    report = check_env_contract(
        task.env,
        task.env_params,
        key=jax.random.key(5),
        num_steps=64,
        reset_key=lambda key: jax.random.split(key)[1],
    )
    assert report.terminations >= report.num_envs, report
    assert report.reward_min == report.reward_max == 1.0, report


def test_k_tick_tasks_count_decisions_and_measure_speed_over_ticks():
    """With ``decision_steps = 4`` the replay's slots hold ceil(max_steps / 4) decisions
    and an episode's mean speed is its distance over its ticks (``info["time"]``), not
    over its decisions."""
    task = make_task("UrbanPedestrians-v0", (("max_steps", 30), ("decision_steps", 4)))
    assert task.max_steps == 8 and task.decision_steps == 4
    info = {
        "collision": jnp.zeros(1, bool),
        "goal": jnp.zeros(1, bool),
        "distance": jnp.full(1, 6.0),
        "time": jnp.full(1, 30, jnp.int32),
    }
    step = Step(None, None, None, None, None, None, info)  # only the info is read
    speed = task.episode_metrics(step, task.env_params)["mean_speed"]
    np.testing.assert_allclose(speed, 6.0 / (30 * 0.1), rtol=1e-6)
