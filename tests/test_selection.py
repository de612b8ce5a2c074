"""Choosing the run's agent on validation episodes (``train.snapshots``): the
snapshots are the online parameters at their thresholds, training is unchanged,
the validation returns are an evaluation's, and the runner saves and loads the
chosen parameters. The sweeps' path (both strategies, sharded, resumed, each run
equal to ``train`` alone) is tested in ``test_sweep.py``, whose sweep keeps a
snapshot."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax
from drqn_jax.checkpoint import load_checkpoint
from drqn_jax.config import ConfigError, load_config
from drqn_jax.runner import load_trained_network, train_run, validated
from drqn_jax.train import (
    VALIDATION_STREAM,
    TrainConfig,
    make_train,
    selection,
    snapshot_thresholds,
)
from tests.helpers import assert_tree_equal, take

SMOKE = ["train.snapshots=2", "train.validation_episodes=2"]
#: smoke.toml (2 envs, 6 episodes of at most 30 steps) with two snapshots: the
#: runner's test below trains the same configuration and reuses the validation
#: program compiled here (``runner.validated``).
SNAP = load_config("smoke", SMOKE).train_config()


@pytest.fixture(scope="module")
def stepped():
    """``SNAP`` one iteration per call: (trainer, final state, the online
    parameters right after each iteration in which a threshold was crossed)."""
    trainer = make_train(SNAP)
    init = jax.jit(trainer.init)
    run = jax.jit(trainer.run, static_argnums=1)
    state = init(jax.random.key(0), SNAP.hyperparams, trainer.env_params)
    at_threshold = {}
    while not bool(state.finished):
        before = int(state.recorded)
        state = run(state, 1)
        for k, threshold in enumerate(snapshot_thresholds(SNAP)):
            if before < threshold <= int(state.recorded):
                at_threshold[k] = state.online
    return trainer, state, at_threshold


def test_thresholds_are_evenly_spaced_and_validated():
    assert snapshot_thresholds(SNAP) == (2, 4)
    assert snapshot_thresholds(TrainConfig(num_episodes=200, snapshots=3)) == (50, 100, 150)
    assert snapshot_thresholds(TrainConfig()) == ()
    with pytest.raises(ValueError, match=r"snapshots = 3: must be in \[0, 2\]"):
        dataclasses.replace(SNAP, snapshots=3)  # 6 episodes, 2 envs: 2 apart at most twice
    for bad, message in [
        ("train.snapshots=-1", r"train\.snapshots = -1: must be in \[0, 2\]"),
        ("train.snapshots=1.5", r"train\.snapshots"),
        ("train.validation_episodes=0", r"train\.validation_episodes = 0: must be an integer"),
    ]:
        with pytest.raises(ConfigError, match=message):
            load_config("smoke", [bad])


def test_snapshots_are_the_online_parameters_at_the_thresholds(stepped):
    _, state, at_threshold = stepped
    assert sorted(at_threshold) == [0, 1]
    for k, params in at_threshold.items():
        assert_tree_equal(take(state.snapshots, k), params)
    assert not np.array_equal(
        np.asarray(at_threshold[0]["q"]["w"]), np.asarray(at_threshold[1]["q"]["w"])
    )
    assert np.all(np.isnan(np.asarray(state.validation)))


def test_snapshots_leave_training_unchanged(stepped):
    """Every leaf but the snapshots equals the run without them, bit for bit."""
    _, state, _ = stepped
    plain = make_train(dataclasses.replace(SNAP, snapshots=0))
    reference = jax.jit(plain.init)(jax.random.key(0), SNAP.hyperparams, plain.env_params)
    reference = jax.jit(plain.run, static_argnums=1)(reference, 200)
    assert reference.snapshots is None and reference.validation is None
    assert_tree_equal(jax.random.key_data(state.key), jax.random.key_data(reference.key))
    assert_tree_equal(
        state.replace(key=None, snapshots=None, validation=None), reference.replace(key=None)
    )


def test_validation_returns_are_an_evaluation_of_each_candidate(stepped):
    """Each candidate's mean greedy return on the validation key's episodes; the
    first snapshot is made to always accelerate so that the candidates differ
    (the tiny run's own parameters all stand still)."""
    trainer, state, _ = stepped
    accelerate = take(state.snapshots, 0)
    accelerate["q"]["b"] = accelerate["q"]["b"].at[0].add(1e3)
    state = state.replace(
        snapshots=jax.tree.map(lambda s, a: s.at[0].set(a), state.snapshots, accelerate)
    )
    returns = np.asarray(validated(trainer, state).validation)
    key = jax.random.fold_in(state.key, VALIDATION_STREAM)
    candidates = [accelerate, take(state.snapshots, 1), state.online]
    expected = [
        drqn_jax.evaluate(
            drqn_jax.drqn_agent(trainer.network, params), key, 2, trainer.env, state.env_params
        )["avg_return"]
        for params in candidates
    ]
    np.testing.assert_allclose(returns, expected, rtol=1e-5)
    assert returns[0] != returns[2]


def test_agent_params_follow_the_validation(stepped):
    trainer, state, _ = stepped
    pending = trainer.agent_params(state)  # not validated yet: the final parameters
    assert_tree_equal(pending, state.online)
    tied = trainer.agent_params(state.replace(validation=jnp.full((3,), -30.0)))
    assert_tree_equal(tied, state.online)  # a tie goes to the latest candidate
    assert selection(jnp.full((3,), -30.0))["selected"] == 2
    for best in range(3):
        returns = jnp.full((3,), -5.0).at[best].set(1.0)
        chosen = trainer.agent_params(state.replace(validation=returns))
        expected = state.online if best == 2 else take(state.snapshots, best)
        assert_tree_equal(chosen, expected)
        assert selection(returns)["selected"] == best
    assert selection(None) == {}
    assert selection(jnp.array([1.0, jnp.nan]))["selected"] == 1
    plain = make_train(dataclasses.replace(SNAP, snapshots=0))
    with pytest.raises(ValueError, match="snapshots = 0"):
        plain.validation_returns(state)


def test_runner_saves_and_loads_the_chosen_agent(tmp_path):
    config = load_config("smoke", SMOKE)
    result = train_run(config, tmp_path, quiet=True)
    assert result.status == "finished"
    validation = np.asarray(result.state.validation)
    assert validation.shape == (3,) and np.all(np.isfinite(validation))
    template = jax.eval_shape(result.trainer.init, config.keys()[0])
    saved, _ = load_checkpoint(tmp_path, template)
    np.testing.assert_array_equal(np.asarray(saved.validation), validation)
    _, params, _ = load_trained_network(config, tmp_path)
    assert_tree_equal(params, result.trainer.agent_params(result.state))
    best = selection(validation)["selected"]
    expected = result.state.online if best == 2 else take(result.state.snapshots, best)
    assert_tree_equal(params, expected)
