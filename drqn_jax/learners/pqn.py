"""Recurrent PQN: Q-learning built for vectorised envs (Gallici et al. 2024,
"Simplifying Deep Temporal Difference Learning"; reference code purejaxql's
``pqn_rnn_gymnax.py``).

It trains the paper's object, a recurrent Q-network whose greedy action is the
agent (Table I; paper §V-B), without the paper's replay and target network:
an update is an ε-greedy rollout of ``rollout_steps`` steps on ``num_envs``
envs, Q(λ) targets computed from the network being trained (no gradient
through them), then ``update_epochs`` epochs over ``num_minibatches``
minibatches of whole env sequences of the squared TD error (global-norm clip,
Adam at the annealed rate). It is served through the same
:class:`~drqn_jax.learners.trainer.Trainer` as the DQN and PPO
(``TrainConfig.algorithm = "pqn"``) and shares PPO's state, rollout
bookkeeping and minibatch epochs (:mod:`drqn_jax.learners.ppo`).

* ε follows the DQN's schedule (:func:`~drqn_jax.learners.dqn.acting.epsilon_of`:
  per training episode, or the share of the step budget, whichever is
  further); purejaxql's ``EPS_DECAY`` is ``epsilon_fraction``.
* The recurrent state is zeroed before the first step of every episode, in
  acting and in the update's unroll, and each minibatch unrolls from the state
  its envs had at the rollout's start.
* Each minibatch's targets bootstrap from the Q-values of the observation
  after the rollout (unrolled with the rollout), so every one of the
  ``rollout_steps`` steps has a target; purejaxql drops the last step instead.
* purejaxql's RAdam, LayerNorm and reward scale are options
  (``TrainConfig.optimizer = "radam"``, ``NetworkConfig.layer_norm``,
  ``Hyperparams.reward_scale``); its "memory window" (steps before the
  rollout that warm the unroll) is not.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.learners.dqn.acting import epsilon_of
from drqn_jax.learners.episodes import record_episodes
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig, annealed, step_share
from drqn_jax.learners.ppo import (
    PPOState,
    minibatch_epochs,
    on_policy_init,
    restarted,
    run_updates,
)
from drqn_jax.learners.task import Task, make_task
from drqn_jax.learners.trainer import Trainer, make_trainer
from drqn_jax.networks import Network, make_network
from drqn_jax.programs import cached_program

__all__ = ["QTransition", "make_pqn", "pqn_loss", "q_lambda_targets"]


class QTransition(NamedTuple):
    """One rollout step of N envs (leaves (N, …)); ``q`` (N, A): the Q-values acted
    on; ``reset``: the carry was zeroed before it (an episode starts)."""

    obs: Any
    q: jax.Array
    action: jax.Array
    reward: jax.Array
    done: jax.Array
    reset: jax.Array


def q_lambda_targets(
    q_next: jax.Array, reward: jax.Array, done: jax.Array, gamma: jax.Array, lam: jax.Array
) -> jax.Array:
    """Peng's Q(λ) targets (T, N) of a rollout: ``q_next`` (T, N) is max_a Q of the
    observation after each step, ``reward`` and ``done`` (T, N) the step's.

    G_{T-1} = r + γ(1 − d) q_next; G_t = r + γ(1 − d)((1 − λ) q_next + λ G_{t+1}):
    λ = 0 is one-step Q-learning, λ = 1 the discounted return to the rollout's
    end, bootstrapped there (purejaxql's ``_compute_targets``).
    """
    not_done = 1.0 - done.astype(jnp.float32)

    def back(g_next, step):
        q, r, nd = step
        g = r + gamma * nd * ((1.0 - lam) * q + lam * g_next)
        return g, g

    last = q_next[-1]  # G_T: the bootstrap itself, so that G_{T-1} = r + γ(1 − d) q_next
    _, targets = jax.lax.scan(back, last, (q_next, reward, not_done), reverse=True)
    return targets


def pqn_loss(
    params: Any,
    network: Network,
    carry: Any,
    batch: QTransition,
    last: QTransition,
    hp: Hyperparams,
) -> tuple[jax.Array, jax.Array]:
    """Half the mean squared TD error of a minibatch of whole sequences (T, B, …)
    unrolled from ``carry`` (B, …) with the observation after them (``last``,
    leaves (B, …)) appended: Q(s_t, a_t) against :func:`q_lambda_targets` of the
    same unroll, held fixed. Returns (loss, loss)."""
    obs = jax.tree.map(lambda xs, x: jnp.concatenate([xs, x[None]]), batch.obs, last.obs)
    resets = jnp.concatenate([batch.reset, last.reset[None]])
    q, _ = network.unroll(params, obs, carry, resets)  # (T + 1, B, A)
    q_max = jax.lax.stop_gradient(jnp.max(q[1:], axis=-1))
    reward = batch.reward * hp.reward_scale
    targets = q_lambda_targets(q_max, reward, batch.done, hp.gamma, hp.q_lambda)
    chosen = jnp.take_along_axis(q[:-1], batch.action[..., None], axis=-1)[..., 0]
    loss = 0.5 * jnp.mean(jnp.square(chosen - targets))
    return loss, loss


def make_pqn(config: TrainConfig) -> Trainer:
    """The :class:`~drqn_jax.learners.trainer.Trainer` of a ``config`` with ``algorithm =
    "pqn"`` (equal configs: the same functions). ``make_train`` calls it."""
    if config.algorithm != "pqn":
        raise ValueError(f"make_pqn: TrainConfig.algorithm = {config.algorithm!r}; use 'pqn'")
    return _make_pqn(config)


@cached_program
def _make_pqn(config: TrainConfig) -> Trainer:
    task = make_task(config.env_id, config.env_overrides)
    network = make_network(task.network(config.network))

    init = on_policy_init(config, task, network, ("epsilon",))

    def act(state: PPOState, key: jax.Array) -> tuple[jax.Array, Any]:
        """ε-greedy actions (N,) and the advanced carry."""
        action, _, carry, _ = _explore(config, task, network, state, key)
        return action, carry

    def update(state: PPOState) -> PPOState:
        carry0 = state.carry
        state, traj = _rollout(config, task, network, state)
        return _learn(config, network, state, traj, carry0)

    return make_trainer(config, task, network, init, act, run_updates(update))


def _explore(
    config: TrainConfig, task: Task, network: Network, state: PPOState, key: jax.Array
) -> tuple[jax.Array, jax.Array, Any, jax.Array]:
    """ε-greedy actions (N,) int32 from the online Q-network, its Q-values (N, A),
    the advanced carry and each env's ε (N,) (its training episode's,
    :func:`epsilon_of`)."""
    hp = state.hparams
    k_explore, k_random = jax.random.split(key)
    q, carry = network.step(state.online, state.obs, restarted(network, state))
    eps = epsilon_of(state.episode, hp, config.num_episodes, step_share(config, state.env_steps))
    shape = state.episode.shape
    random_action = jax.random.randint(k_random, shape, 0, task.num_actions, jnp.int32)
    greedy = jnp.argmax(q, axis=-1).astype(jnp.int32)
    action = jnp.where(jax.random.uniform(k_explore, shape) < eps, random_action, greedy)
    return action, q, carry, eps


def _rollout(
    config: TrainConfig, task: Task, network: Network, state: PPOState
) -> tuple[PPOState, QTransition]:
    """``rollout_steps`` ε-greedy steps of the N envs: the moved state (its ended
    episodes recorded, with their ε) and the trajectory (leaves (T, N, …))."""
    zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)

    def step(state, _):
        key, k_act, k_env = jax.random.split(state.key, 3)
        action, q, carry, eps = _explore(config, task, network, state, k_act)
        env = jax.vmap(task.step, (0, 0, 0, None))(
            jax.random.split(k_env, config.num_envs), state.env_state, action, state.env_params
        )
        done = env.terminated | env.truncated
        traj = QTransition(state.obs, q, action, env.reward, done, state.done)
        moved, metrics = record_episodes(
            task, config.num_episodes, state, env, done, zero_f, zero_i, {"epsilon": eps}
        )
        return moved.replace(key=key, carry=carry, done=done, metrics=metrics), traj

    return jax.lax.scan(step, state, None, config.rollout_steps)


def _learn(
    config: TrainConfig, network: Network, state: PPOState, traj: QTransition, carry0: Any
) -> PPOState:
    """The update of one rollout: epochs of minibatch steps on :func:`pqn_loss`
    (:func:`~drqn_jax.learners.ppo.minibatch_epochs`) at the annealed rate."""
    hp = state.hparams
    last = jax.tree.map(lambda x: x[0], traj)._replace(obs=state.obs, reset=state.done)
    lr = annealed(
        hp, state.recorded, config.num_episodes, step_share(config, state.env_steps)
    ).learning_rate

    def grads_of(params, envs):
        take = functools.partial(jnp.take, indices=envs, axis=1)
        take0 = functools.partial(jnp.take, indices=envs, axis=0)
        batch, mb_last = jax.tree.map(take, traj), jax.tree.map(take0, last)
        mb_carry = jax.tree.map(take0, carry0)
        return jax.grad(pqn_loss, has_aux=True)(params, network, mb_carry, batch, mb_last, hp)

    return minibatch_epochs(config, state, lr, grads_of)
