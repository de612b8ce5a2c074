"""Recurrent PQN (drqn_jax/learners/pqn.py): Q(λ) targets against a hand-computed
example, the recurrent state's resets in acting and in the update's unroll, the
loss at its targets, a chunked run bit-identical to one shot on a gymnax env
the benchmarks do not use, and the config's rules."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.gymnax_validation import SMALL, pqn_config
from drqn_jax.config import load_config
from drqn_jax.learners import Hyperparams, TrainConfig, common, make_train
from drqn_jax.learners.hyperparams import agent_name
from drqn_jax.learners.pqn import QTransition, _explore, pqn_loss, q_lambda_targets
from drqn_jax.networks import NetworkConfig


@pytest.mark.parametrize(
    ("lam", "expected"),
    [
        (0.5, [1.25, 0.0, 2.5]),  # G_0 = 1 + ½((1 − ½)·1 + ½·G_1), G_1 = 0 (ended)
        (0.0, [1.5, 0.0, 2.5]),  # one-step Q-learning: r + γ(1 − d) max Q'
        (1.0, [1.0, 0.0, 2.5]),  # the discounted return, cut where the episode ends
    ],
)
def test_q_lambda_targets_by_hand(lam, expected):
    """Three steps of one env, γ = ½, the episode ending at step 1:
    max Q of the next observations 1, 2, 3; rewards 1, 0, 1."""
    q_next = jnp.array([[1.0], [2.0], [3.0]])
    reward = jnp.array([[1.0], [0.0], [1.0]])
    done = jnp.array([[False], [True], [False]])
    got = q_lambda_targets(q_next, reward, done, jnp.float32(0.5), jnp.float32(lam))
    np.testing.assert_allclose(np.asarray(got)[:, 0], expected, rtol=1e-6)


@pytest.fixture(scope="module")
def rollout():
    """A 64-step rollout of 4 CartPole envs under a fresh Q-network (episodes end in it)."""
    config = dataclasses.replace(pqn_config(), num_envs=4, num_minibatches=2)
    trainer = make_train(config)
    state = trainer.init(jax.random.key(0))
    policy = functools.partial(_explore, config, trainer.task, trainer.network)
    after, traj = jax.jit(lambda s: common.rollout(config, trainer.task, policy, QTransition, s))(
        state
    )
    return trainer, state, after, traj


def test_update_unroll_restarts_the_recurrent_state_where_acting_did(rollout):
    """Unrolled from the rollout's first carry with the stored resets, the network
    gives back the Q-values it acted on; without the resets (a carry leaking
    across an auto-reset, purejaxrl#23) it does not, once an episode has ended."""
    trainer, state, after, traj = rollout
    assert int(after.recorded) > 0 and bool(traj.reset[1:].any())

    def replay(resets):
        return np.asarray(trainer.network.unroll(state.online, traj.obs, state.carry, resets)[0])

    np.testing.assert_allclose(replay(traj.reset), np.asarray(traj.q), rtol=1e-4, atol=1e-5)
    leaked = replay(jnp.zeros_like(traj.reset))
    first_reset = int(np.argmax(np.asarray(traj.reset).any(axis=1)))
    assert not np.allclose(leaked[first_reset:], np.asarray(traj.q)[first_reset:])


def test_loss_is_half_the_squared_error_against_the_q_lambda_targets(rollout):
    """At the parameters that acted, the loss is ½·mean (Q(s, a) − G^λ)² with the
    targets from the acted Q-values, the Q-values of the observation after the
    rollout and the scaled rewards."""
    trainer, state, after, traj = rollout
    hp = state.hparams
    carry = common.restarted(trainer.network, after)
    q_after, _ = jax.jit(trainer.network.step)(state.online, after.obs, carry)  # not op by op
    q_next = jnp.concatenate([traj.q[1:], q_after[None]]).max(axis=-1)
    reward = traj.reward * hp.reward_scale  # purejaxql's 0.1 in pqn_config
    targets = q_lambda_targets(q_next, reward, traj.done, hp.gamma, hp.q_lambda)
    chosen = jnp.take_along_axis(traj.q, traj.action[..., None], axis=-1)[..., 0]
    expected = 0.5 * float(jnp.mean((chosen - targets) ** 2))
    last = jax.tree.map(lambda x: x[0], traj)._replace(obs=after.obs, reset=after.done)
    loss, _ = jax.jit(pqn_loss, static_argnums=1)(
        state.online, trainer.network, state.carry, traj, last, hp
    )
    assert float(loss) == pytest.approx(expected, rel=1e-4)


def test_chunked_run_on_acrobot_ends_bit_identical_to_one_shot():
    """PQN trains through ``make_train`` on any gymnax env (Acrobot-v1, three
    actions): updates after the episode budget is met change nothing, so chunks
    of 2 updates end where one ``train`` call does, with every metric recorded."""
    config = TrainConfig(
        env_id="gymnax:Acrobot-v1",
        env_overrides=(("max_steps_in_episode", 20),),
        network=NetworkConfig(kind="drqn", **SMALL),
        algorithm="pqn",
        num_envs=4,
        num_episodes=12,
        rollout_steps=8,
        update_epochs=2,
        num_minibatches=2,
        chunk_iterations=3,
        hyperparams=Hyperparams(learning_rate=1e-3),
    )
    trainer = make_train(config)
    key = jax.random.key(1)
    params, metrics = jax.jit(trainer.train)(key)
    run = jax.jit(trainer.run, static_argnums=1)
    state = trainer.init(key)
    while not bool(state.finished):
        state = run(state, 2)
    state = run(state, 2)  # past the end: nothing changes
    for a, b in zip(
        jax.tree.leaves((params, metrics)),
        jax.tree.leaves((state.online, state.metrics)),
        strict=True,
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert np.all(np.asarray(metrics["length"]) == 20)
    assert np.all(np.isfinite(np.asarray(metrics["mean_loss"])))
    assert float(np.max(np.asarray(metrics["mean_loss"]))) > 0.0
    eps = np.asarray(metrics["epsilon"])
    assert eps[0] == pytest.approx(1.0) and eps[-1] == pytest.approx(0.1)


def test_config_rules_name_the_learner():
    assert agent_name(pqn_config()) == "pqn"
    feed_forward = dataclasses.replace(pqn_config(), network=NetworkConfig(kind="dqn", **SMALL))
    assert agent_name(feed_forward) == "pqn-ff"
    with pytest.raises(ValueError, match="num_minibatches = 16: must divide num_envs \\(8\\)"):
        dataclasses.replace(pqn_config(), num_envs=8)
    with pytest.raises(ValueError, match="algorithm 'pqn' learns from the reward alone"):
        dataclasses.replace(pqn_config(), hyperparams=Hyperparams(imitation_weight=1.0))
    with pytest.raises(ValueError, match="q_lambda"):
        Hyperparams(q_lambda=1.5)
    with pytest.raises(ValueError, match=r"reward_scale = 0\.1: only algorithm 'pqn'"):
        TrainConfig(algorithm="ppo", hyperparams=Hyperparams(reward_scale=0.1))
    with pytest.raises(ValueError, match="optimizer = 'sgd'"):
        dataclasses.replace(pqn_config(), optimizer="sgd")
    with pytest.raises(ValueError, match="layer_norm"):
        NetworkConfig(layer_norm=1)
    options = ["train.algorithm=pqn", "train.num_minibatches=1", "network.layer_norm=true"]
    config = load_config("smoke", [*options, "train.optimizer=radam", "train.reward_scale=0.1"])
    train = config.train_config()
    assert (train.algorithm, train.optimizer, train.network.layer_norm) == ("pqn", "radam", True)
    assert float(train.hyperparams.reward_scale) == pytest.approx(0.1)


def test_layer_norm_normalises_each_dense_layer_before_its_relu():
    """With ``layer_norm``, the MLP torso's and the FC layer's pre-activations
    have zero mean and unit variance over their units at initialisation (scale
    1, bias 0); the parameters carry a scale and a bias for each."""
    from drqn_jax.layers import dense_relu
    from drqn_jax.networks import make_network

    config = NetworkConfig(kind="drqn", torso="mlp", obs_size=4, layer_norm=True, **SMALL)
    params = make_network(config).init(jax.random.key(0))
    for layer in (*params["torso"], params["fc"]):
        assert set(layer["norm"]) == {"scale", "bias"}
    x = jax.random.normal(jax.random.key(1), (8, 4)) * 5.0 + 3.0
    layer = params["torso"][0]
    y = x @ layer["w"] + layer["b"]
    z = (y - y.mean(-1, keepdims=True)) / jnp.sqrt(y.var(-1, keepdims=True) + 1e-6)
    np.testing.assert_allclose(
        np.asarray(dense_relu(layer, x)), np.maximum(np.asarray(z), 0.0), rtol=1e-4, atol=1e-5
    )
    plain = make_network(dataclasses.replace(config, layer_norm=False)).init(jax.random.key(0))
    assert "norm" not in plain["fc"]


def _one_update(memory_window: int):
    config = dataclasses.replace(
        pqn_config(), num_envs=4, num_minibatches=2, update_epochs=1, memory_window=memory_window
    )
    trainer = make_train(config)
    state = trainer.init(jax.random.key(0))
    return trainer, state, jax.jit(trainer.run, static_argnums=1)(state, 1)


def test_memory_window_first_update_trains_the_rollout_alone():
    """Before the first update the memory is padding (weight 0, the rollout's
    carry restarted as in acting): that update gives the parameters of a run
    without a memory window, up to float rounding."""
    _, _, plain = _one_update(0)
    _, _, windowed = _one_update(4)
    assert plain.memory is None and windowed.memory.obs.shape[0] == 4
    for a, b in zip(jax.tree.leaves(plain.online), jax.tree.leaves(windowed.online), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
    assert int(windowed.grad_steps) == int(plain.grad_steps) > 0


def test_memory_window_keeps_the_last_steps_with_the_state_acted_from():
    """After an update the memory holds the rollout's last W steps: unrolled from
    the stored state of its first step with the stored resets, the parameters
    that acted give back the Q-values acted on; the next update changes them."""
    trainer, state, after = _one_update(4)
    memory = after.memory
    start = jax.tree.map(lambda x: x[0], memory.carry)
    q, _ = jax.jit(trainer.network.unroll)(state.online, memory.obs, start, memory.reset)
    np.testing.assert_allclose(np.asarray(q), np.asarray(memory.q), rtol=1e-4, atol=1e-5)
    later = jax.jit(trainer.run, static_argnums=1)(after, 1)
    assert not np.allclose(np.asarray(later.memory.q), np.asarray(memory.q))


def test_memory_window_config_rules():
    with pytest.raises(ValueError, match=r"memory_window = 4: only algorithm 'pqn'"):
        TrainConfig(algorithm="ppo", memory_window=4)
    with pytest.raises(ValueError, match=r"memory_window = 200: must be in \[0, 128\]"):
        dataclasses.replace(pqn_config(), rollout_steps=128, memory_window=200)
    config = load_config("smoke", ["train.algorithm=pqn", "train.num_minibatches=1"])
    assert config.train_config().memory_window == 0
    windowed = load_config(
        "smoke", ["train.algorithm=pqn", "train.num_minibatches=1", "train.memory_window=4"]
    )
    assert windowed.train_config().memory_window == 4
