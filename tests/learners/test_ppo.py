"""Recurrent PPO (drqn_jax/learners/ppo.py): GAE, the loss at the rollout's parameters,
the recurrent state's resets in acting and in the update's unroll, the
per-episode bookkeeping and budget it shares with the DQN, and learning."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.gymnax_validation import ppo_config, run_recipe
from drqn_jax.learners import Hyperparams, TrainConfig, make_train
from drqn_jax.learners.common import rollout as common_rollout
from drqn_jax.learners.ppo import Transition, _sample, actor_critic, gae, ppo_loss

HP = ppo_config().hyperparams


def test_gae_matches_the_textbook_recursion():
    rng = np.random.default_rng(0)
    t, n = 7, 3
    value, reward = rng.normal(size=(t, n)), rng.normal(size=(t, n))
    done = rng.random((t, n)) < 0.3
    last = rng.normal(size=n)
    adv, target = gae(*(jnp.asarray(x, jnp.float32) for x in (value, reward)), done, last, HP)
    expected = np.zeros((t, n))
    running, next_value = np.zeros(n), last
    for i in reversed(range(t)):
        keep = 1.0 - done[i]
        delta = reward[i] + HP.gamma * next_value * keep - value[i]
        running = delta + HP.gamma * HP.gae_lambda * keep * running
        expected[i], next_value = running, value[i]
    np.testing.assert_allclose(np.asarray(adv), expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(target), expected + value, rtol=1e-5, atol=1e-5)


@pytest.fixture(scope="module")
def rollout():
    """A 64-step rollout of 4 CartPole envs under a fresh policy (episodes end in it)."""
    config = dataclasses.replace(ppo_config(), rollout_steps=64)
    trainer = make_train(config)
    network = actor_critic(config, trainer.task)
    state = trainer.init(jax.random.key(0))
    carry0 = state.carry
    policy = functools.partial(_sample, trainer.task, network)
    after, traj = jax.jit(lambda s: common_rollout(config, trainer.task, policy, Transition, s))(
        state
    )
    return trainer, network, state, carry0, after, traj


def test_update_unroll_restarts_the_recurrent_state_where_acting_did(rollout):
    """Unrolled from the rollout's first carry with the stored resets, the network
    gives back the values and log-probabilities it acted with; without the resets
    (the bug class of purejaxrl#23) it does not, once an episode has ended."""
    trainer, network, state, carry0, after, traj = rollout
    assert int(after.recorded) > 0 and bool(traj.reset[1:].any())
    n_act = trainer.task.num_actions

    def replay(resets):
        out, _ = network.unroll(state.online, traj.obs, carry0, resets)
        log_probs = jax.nn.log_softmax(out[..., :n_act])
        taken = jnp.take_along_axis(log_probs, traj.action[..., None], axis=-1)[..., 0]
        return np.asarray(out[..., n_act]), np.asarray(taken)

    value, log_prob = replay(traj.reset)
    np.testing.assert_allclose(value, np.asarray(traj.value), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(log_prob, np.asarray(traj.log_prob), rtol=1e-4, atol=1e-5)
    value_no_reset, _ = replay(jnp.zeros_like(traj.reset))
    first_reset = int(np.argmax(np.asarray(traj.reset).any(axis=1)))
    assert not np.allclose(value_no_reset[first_reset:], np.asarray(traj.value)[first_reset:])


def test_loss_at_the_rollouts_parameters(rollout):
    """At the parameters that acted, every ratio is 1: the actor term is minus the
    mean normalised advantage (0), and the value loss is half the mean squared
    error of the values against the targets."""
    trainer, network, state, carry0, after, traj = rollout
    n_act = trainer.task.num_actions
    out, _ = network.step(after.online, after.obs, after.carry)
    adv, target = gae(traj.value, traj.reward, traj.done, out[..., n_act], HP)
    total, parts = ppo_loss(state.online, network, n_act, carry0, traj, adv, target, HP)
    assert abs(float(parts["actor"])) < 1e-5
    mse = 0.5 * float(jnp.mean((traj.value - target) ** 2))
    assert float(parts["critic"]) == pytest.approx(mse, rel=1e-4)
    expected = parts["actor"] + HP.vf_coef * parts["critic"] - HP.ent_coef * parts["entropy"]
    assert float(total) == pytest.approx(float(expected), rel=1e-6)


def test_rollout_records_every_ended_episode(rollout):
    """The rollout's bookkeeping is the DQN's: each episode that ended is written at
    its index (episodes end out of order) with its return and length, and the
    env steps add up."""
    *_, after, traj = rollout
    done = np.asarray(traj.done)
    assert int(after.recorded) == int(done.sum())
    assert int(after.env_steps) == done.size
    lengths = np.asarray(after.metrics["length"])
    written = lengths > 0
    assert int(written.sum()) == int(after.recorded)
    returns = np.asarray(after.metrics["episode_return"])[written]
    np.testing.assert_array_equal(returns, lengths[written].astype(np.float32))  # +1 a step


def test_config_validation():
    with pytest.raises(ValueError, match="num_minibatches = 3: must divide num_envs"):
        TrainConfig(algorithm="ppo", num_envs=4, num_minibatches=3)
    with pytest.raises(ValueError, match="clip_eps"):
        Hyperparams(clip_eps=0.0)
    with pytest.raises(ValueError, match="algorithm 'ppo' learns from the reward alone"):
        TrainConfig(algorithm="ppo", num_envs=4, hyperparams=Hyperparams(explore_guide=0.5))
    with pytest.raises(ValueError, match="stored_state = 1: algorithm 'ppo' has no replay"):
        TrainConfig(algorithm="ppo", num_envs=4, stored_state=1)
    with pytest.raises(ValueError, match="algorithm = 'sac': must be one of"):
        TrainConfig(algorithm="sac")


def test_chunked_run_ends_bit_identical_to_one_shot():
    """Updates after the episode budget is met change nothing: chunks of 1 and 3
    updates end where the whole run in one ``train`` call does. That call's network
    writes out its scans 3 steps per loop iteration (``scan_unroll = 3``: a 16-step
    rollout as a loop over five blocks of 3, then the last step), the chunks' one
    step (the recipe's): the same bits (the default 9 is test_networks')."""
    config = dataclasses.replace(
        ppo_config(num_episodes=24, num_env_steps=0), rollout_steps=16, chunk_iterations=5
    )
    trainer = make_train(config)
    assert config.network.scan_unroll == 1
    unrolled = dataclasses.replace(config.network, scan_unroll=3)
    key = jax.random.key(1)
    params, metrics = jax.jit(make_train(dataclasses.replace(config, network=unrolled)).train)(key)
    run = jax.jit(trainer.run, static_argnums=1)  # one program per chunk size
    for chunk in (1, 3):
        state = trainer.init(key)
        while not bool(state.finished):
            state = run(state, chunk)
        state = run(state, chunk)  # past the end: nothing changes
        for a, b in zip(
            jax.tree.leaves((params, metrics)),
            jax.tree.leaves((state.online, state.metrics)),
            strict=True,
        ):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_ppo_learns_cartpole():
    """250 updates (1.3·10⁵ env steps, a quarter of the benchmark's budget): the
    greedy policy balances far longer than a random one (about 22 steps)."""
    out = run_recipe(ppo_config(num_env_steps=250 * 4 * 128), 1, episodes=20)
    assert min(out["mean_return"]) > 100.0, out
