"""Recurrent PQN (Gallici et al. 2024; purejaxql's ``pqn_rnn_gymnax.py``): the paper's
recurrent Q-network (Table I; paper §V-B) without replay or target network.

One update: an ε-greedy rollout (the DQN's ε schedule), Q(λ) targets from the trained
network (no gradient), then minibatch epochs of the squared TD error. Targets also
bootstrap from the observation after the rollout (purejaxql drops the last step).
"""

from __future__ import annotations

import functools
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.learners.common import (
    budget_met,
    epsilon_of,
    init_counters,
    init_metrics,
    minibatch_epochs,
    per_decision,
    restarted,
    rollout,
    run_updates,
)
from drqn_jax.learners.hyperparams import Hyperparams, TrainConfig, annealed, step_share
from drqn_jax.learners.optim import optimizer
from drqn_jax.learners.task import Task, make_task
from drqn_jax.learners.trainer import Trainer, make_trainer
from drqn_jax.networks import Network, make_network
from drqn_jax.programs import cached_program
from drqn_jax.pytree import pytree_dataclass

__all__ = ["PQNState", "QTransition", "make_pqn", "pqn_loss", "q_lambda_targets"]

#: The per-episode metrics PQN adds to the shared ones: the ε the episode ran with.
PQN_METRICS = ("epsilon",)


@pytree_dataclass
class PQNState:
    """Everything a PQN run carries between updates (and checkpoints); per-env leaves
    (N, …), ``online`` the Q-network's parameters, ``done`` (N,) restarts the carry."""

    key: jax.Array
    hparams: Hyperparams
    env_params: Any
    env_state: Any
    obs: Any
    carry: Any
    done: jax.Array
    online: Any
    opt_state: Any
    episode: jax.Array
    ep_return: jax.Array
    ep_length: jax.Array
    ep_loss_sum: jax.Array
    ep_loss_count: jax.Array
    episodes_started: jax.Array
    recorded: jax.Array
    grad_steps: jax.Array
    env_steps: jax.Array
    step_budget: jax.Array  # () int32 TrainConfig.num_env_steps (0: none)
    metrics: dict[str, jax.Array]
    #: The protocol's candidates' validation metrics: none, PQN selects no snapshot.
    validation: ClassVar[None] = None

    @property
    def finished(self) -> jax.Array:
        return budget_met(self)


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
    """Peng's Q(λ) targets (T, N) from ``q_next`` = max_a Q after each step, ``reward``,
    ``done`` (T, N): G_t = r + γ(1 − d)((1 − λ) q_next + λ G_{t+1}) (purejaxql's)."""
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
    """Half the mean squared TD error of sequences (T, B, …) plus ``last`` (B, …),
    unrolled from ``carry``, against fixed :func:`q_lambda_targets`: (loss, loss)."""
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
    """The :class:`~drqn_jax.learners.trainer.Trainer` of an ``algorithm = "pqn"`` config."""
    if config.algorithm != "pqn":
        raise ValueError(f"make_pqn: TrainConfig.algorithm = {config.algorithm!r}; use 'pqn'")
    return _make_pqn(config)


@cached_program
def _make_pqn(config: TrainConfig) -> Trainer:
    task = make_task(config.env_id, config.env_overrides)
    network = make_network(task.network(config.network))

    def init(key: jax.Array, hparams: Hyperparams | None = None, env_params: Any = None):
        """The state before the first update."""
        hp = config.hyperparams if hparams is None else hparams
        env_params = task.env_params if env_params is None else env_params
        return _init_state(config, task, network, key, hp, env_params)

    def act(state: PQNState, key: jax.Array) -> tuple[jax.Array, Any]:
        """ε-greedy actions (N,) and the advanced carry."""
        action, carry, _, _ = _explore(config, task, network, state, key)
        return action, carry

    def update(state: PQNState) -> PQNState:
        """One update: a rollout, then epochs of minibatch steps on its TD errors."""
        carry0 = state.carry
        state, traj = _rollout(config, task, network, state)
        return _learn(config, task, network, state, traj, carry0)

    return make_trainer(config, task, network, init, act, run_updates(update))


def _init_state(
    config: TrainConfig,
    task: Task,
    network: Network,
    key: jax.Array,
    hp: Hyperparams,
    env_params: Any,
) -> PQNState:
    """N envs reset, a fresh Q-network and optimiser, empty metrics."""
    n_env = config.num_envs
    key, k_net, k_env = jax.random.split(key, 3)
    params = network.init(k_net)
    obs, env_state = jax.vmap(task.reset, (0, None))(jax.random.split(k_env, n_env), env_params)
    return PQNState(
        key=key,
        hparams=hp,
        env_params=env_params,
        env_state=env_state,
        obs=obs,
        carry=network.initial_carry((n_env,)),
        done=jnp.zeros((n_env,), bool),
        online=params,
        opt_state=optimizer(
            config.optimizer, hp.learning_rate, hp.adam_b1, hp.adam_b2, hp.adam_eps
        ).init(params),
        metrics=init_metrics(task, config.num_episodes, PQN_METRICS),
        **init_counters(n_env, config.num_env_steps),
    )


def _explore(
    config: TrainConfig, task: Task, network: Network, state: PQNState, key: jax.Array
) -> tuple[jax.Array, Any, dict[str, jax.Array], dict[str, jax.Array]]:
    """The ε-greedy policy: actions (N,) int32, the carry, Q-values (N, A) and ε (N,)."""
    hp = state.hparams
    k_explore, k_random = jax.random.split(key)
    q, carry = network.step(state.online, state.obs, restarted(network, state))
    eps = epsilon_of(state.episode, hp, config.num_episodes, step_share(config, state.env_steps))
    shape = state.episode.shape
    random_action = jax.random.randint(k_random, shape, 0, task.num_actions, jnp.int32)
    greedy = jnp.argmax(q, axis=-1).astype(jnp.int32)
    action = jnp.where(jax.random.uniform(k_explore, shape) < eps, random_action, greedy)
    return action, carry, {"q": q}, {"epsilon": eps}


def _rollout(
    config: TrainConfig, task: Task, network: Network, state: PQNState
) -> tuple[PQNState, QTransition]:
    """``rollout_steps`` ε-greedy steps: the moved state and the trajectory (T, N, …)."""
    policy = functools.partial(_explore, config, task, network)
    return rollout(config, task, policy, QTransition, state)


def _learn(
    config: TrainConfig,
    task: Task,
    network: Network,
    state: PQNState,
    traj: QTransition,
    carry0: Any,
) -> PQNState:
    """One rollout's update: minibatch epochs on :func:`pqn_loss` at the annealed rate."""
    hp = state.hparams
    td_hp = per_decision(hp, task)
    last = jax.tree.map(lambda x: x[0], traj)._replace(obs=state.obs, reset=state.done)
    lr = annealed(
        hp, state.recorded, config.num_episodes, step_share(config, state.env_steps)
    ).learning_rate

    def grads_of(params, envs):
        take = functools.partial(jnp.take, indices=envs, axis=1)
        take0 = functools.partial(jnp.take, indices=envs, axis=0)
        batch, mb_last = jax.tree.map(take, traj), jax.tree.map(take0, last)
        mb_carry = jax.tree.map(take0, carry0)
        return jax.grad(pqn_loss, has_aux=True)(params, network, mb_carry, batch, mb_last, td_hp)

    return minibatch_epochs(config, state, lr, grads_of)
