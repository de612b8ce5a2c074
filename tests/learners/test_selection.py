"""Choosing the run's agent on validation episodes (``train.snapshots``): the
snapshots are the online parameters at their thresholds, training is unchanged,
the validation metrics are an evaluation's, the selection rules pick what they
say, and the runner saves and loads the chosen parameters. The sweeps' path
(both strategies, sharded, resumed, each run equal to ``train`` alone) is tested
in ``test_sweep.py``, whose sweep keeps a snapshot."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax
from drqn_jax.config import ConfigError, load_config
from drqn_jax.experiments.checkpoint import load_checkpoint
from drqn_jax.experiments.runner import init_program, load_trained_network, train_run, validated
from drqn_jax.learners import TrainConfig, make_train
from drqn_jax.learners.common import (
    VALIDATION_STREAM,
    chosen_candidate,
    selection,
    snapshot_thresholds,
)
from drqn_jax.learners.hyperparams import SELECT_BY
from tests.helpers import SMOKE_CHUNK, assert_tree_equal, take

#: What validation measures per candidate of the paper's env.
VALIDATION_METRICS = ("return", "collision_free", "speed")

SMOKE = ["train.snapshots=2", "train.validation_episodes=2", "train.chunk_iterations=1"]
#: smoke.toml (2 envs, 6 episodes of at most 30 steps) with two snapshots, one
#: iteration per chunk: the runner's test below trains the same configuration
#: with the programs compiled here (init, run and ``runner.validated``).
SNAP = load_config("smoke", SMOKE).train_config()


@pytest.fixture(scope="module")
def stepped():
    """``SNAP`` one iteration per call: (trainer, final state, the online
    parameters right after each iteration in which a threshold was crossed)."""
    trainer = make_train(SNAP)
    run = jax.jit(trainer.run, static_argnums=1)
    state = init_program(trainer)(jax.random.key(0))
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
        ("train.select_by='speed'", r"train\.select_by = 'speed': must be one of 'return', 'safe'"),
        (
            "train.select_speed_floor=-1",
            r"train\.select_speed_floor = -1\.0: out of range, allowed 0\.0 <= value",
        ),
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
    assert sorted(state.validation) == sorted(VALIDATION_METRICS)
    assert all(np.all(np.isnan(np.asarray(v))) for v in state.validation.values())


def test_snapshots_leave_training_unchanged(stepped):
    """Every leaf but the snapshots equals the run without them, bit for bit. The
    run without them goes in chunks of smoke.toml's ``train``: the programs of
    test_cli's smoke run."""
    _, state, _ = stepped
    plain = make_train(dataclasses.replace(SNAP, snapshots=0))
    reference = init_program(plain)(jax.random.key(0))
    run = jax.jit(plain.run, static_argnums=1)
    while not bool(reference.finished):
        reference = run(reference, SMOKE_CHUNK)
    assert reference.snapshots is None and reference.validation is None
    assert_tree_equal(jax.random.key_data(state.key), jax.random.key_data(reference.key))
    assert_tree_equal(
        state.replace(key=None, snapshots=None, validation=None), reference.replace(key=None)
    )


def test_validation_metrics_are_an_evaluation_of_each_candidate(stepped):
    """Each candidate's mean greedy return, collision-free rate and speed on the
    validation key's episodes, as ``evaluate`` reports them; the first snapshot
    is made to always accelerate so that the candidates differ (the tiny run's
    own parameters all stand still)."""
    trainer, state, _ = stepped
    accelerate = take(state.snapshots, 0)
    accelerate["q"]["b"] = accelerate["q"]["b"].at[0].add(1e3)
    state = state.replace(
        snapshots=jax.tree.map(lambda s, a: s.at[0].set(a), state.snapshots, accelerate)
    )
    validation = validated(trainer, state).validation
    key = jax.random.fold_in(state.key, VALIDATION_STREAM)
    candidates = [accelerate, take(state.snapshots, 1), state.online]
    evaluations = [
        drqn_jax.evaluate(
            drqn_jax.drqn_agent(trainer.network, params), key, 2, trainer.task.env, state.env_params
        )
        for params in candidates
    ]
    for metric, (name, scale) in {
        "return": ("avg_return", 1.0),
        "collision_free": ("collision_free_rate", 1.0),
        "speed": ("avg_speed_kmh", 1 / 3.6),
    }.items():
        expected = [e[name] * scale for e in evaluations]
        np.testing.assert_allclose(np.asarray(validation[metric]), expected, rtol=1e-5)
    assert validation["return"][0] != validation["return"][2]
    assert validation["speed"][0] > validation["speed"][2]


def _validation(returns, collision_free=(1.0, 1.0, 1.0), speed=(2.0, 2.0, 2.0)):
    values = (returns, collision_free, speed)
    return {
        name: jnp.asarray(v, jnp.float32)
        for name, v in zip(VALIDATION_METRICS, values, strict=True)
    }


def test_agent_params_follow_the_validation(stepped):
    trainer, state, _ = stepped
    hp = state.hparams
    pending = trainer.agent_params(state)  # not validated yet: the final parameters
    assert_tree_equal(pending, state.online)
    tied = trainer.agent_params(state.replace(validation=_validation([-30.0] * 3)))
    assert_tree_equal(tied, state.online)  # a tie goes to the latest candidate
    assert selection(_validation([-30.0] * 3), hp)["selected"] == 2
    for best in range(3):
        returns = [-5.0] * 3
        returns[best] = 1.0
        validation = _validation(returns)
        chosen = trainer.agent_params(state.replace(validation=validation))
        expected = state.online if best == 2 else take(state.snapshots, best)
        assert_tree_equal(chosen, expected)
        assert selection(validation, hp)["selected"] == best
    assert selection(None, hp) == {}
    assert selection(_validation([1.0, 2.0, jnp.nan]), hp)["selected"] == 2
    plain = make_train(dataclasses.replace(SNAP, snapshots=0))
    with pytest.raises(ValueError, match="snapshots = 0"):
        plain.validation_metrics(state)


@pytest.mark.parametrize(
    ("select_by", "floor", "validation", "expected"),
    [
        # the best return, whatever its collisions
        ("return", 0.0, ([5.0, 9.0, 1.0], [0.9, 0.5, 0.8], [2.0, 3.0, 1.0]), 1),
        # the most collision-free at any speed; then the latest
        ("safe", 0.0, ([5.0, 9.0, 1.0], [0.9, 0.5, 0.8], [2.0, 3.0, 1.0]), 0),
        ("safe", 0.0, ([5.0, 9.0, 5.0], [0.9, 0.5, 0.9], [2.0, 3.0, 1.0]), 2),
        # of equally collision-free candidates, the best return
        ("safe", 0.0, ([5.0, 9.0, 1.0], [0.9, 0.9, 0.9], [2.0, 3.0, 1.0]), 1),
        # the floor rules out the safest (too slow): the safest of the rest
        ("safe", 1.9, ([5.0, 9.0, 1.0], [0.9, 0.5, 1.0], [2.0, 3.0, 1.0]), 0),
        ("safe", 2.5, ([5.0, 9.0, 1.0], [0.9, 0.5, 1.0], [2.0, 3.0, 1.0]), 1),
        # none as fast as the floor: the final parameters
        ("safe", 5.0, ([5.0, 9.0, 1.0], [0.9, 0.5, 1.0], [2.0, 3.0, 1.0]), 2),
        # not validated: the final parameters
        ("safe", 0.0, ([5.0, 9.0, 1.0], [0.9, jnp.nan, 1.0], [2.0, 3.0, 1.0]), 2),
    ],
)
def test_selection_rules(select_by, floor, validation, expected):
    hp = dataclasses.replace(
        SNAP.hyperparams, select_by=SELECT_BY.index(select_by), select_speed_floor=floor
    )
    validation = _validation(*validation)
    assert int(chosen_candidate(validation, hp)) == expected
    record = selection(validation, hp)
    assert record["selected"] == expected
    assert record["validation_speed_kmh"] == pytest.approx(
        [3.6 * float(v) for v in validation["speed"]]
    )


def test_runner_saves_and_loads_the_chosen_agent(tmp_path):
    config = load_config("smoke", SMOKE)
    result = train_run(config, tmp_path, quiet=True)
    assert result.status == "finished"
    validation = jax.tree.map(np.asarray, result.state.validation)
    assert all(v.shape == (3,) and np.all(np.isfinite(v)) for v in validation.values())
    template = jax.eval_shape(result.trainer.init, config.keys()[0])
    saved, _ = load_checkpoint(tmp_path, template)
    assert_tree_equal(saved.validation, validation)
    _, params, _ = load_trained_network(config, tmp_path)
    assert_tree_equal(params, result.trainer.agent_params(result.state))
    best = selection(validation, result.state.hparams)["selected"]
    expected = result.state.online if best == 2 else take(result.state.snapshots, best)
    assert_tree_equal(params, expected)
