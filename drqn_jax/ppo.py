"""Recurrent PPO, a learner of another family (Schulman et al. 2017; the project's).

Laid out like PureJaxRL's ``ppo_rnn.py``: ``make_ppo(config)`` returns a
:class:`PPOTrainer` of pure functions — ``init(key, hparams) -> PPOState``,
``update(state) -> PPOState`` (one rollout of ``num_steps`` steps on
``num_envs`` envs, generalised advantage estimation, ``update_epochs`` epochs
of clipped-surrogate updates over ``num_minibatches`` minibatches of whole
env sequences) and ``train(key, hparams) -> (params, metrics)`` (``lax.scan``
over ``num_updates`` updates). It shares the DRQN's environment interface
(:class:`~drqn_jax.task.Task`, any env of the gymnax contract), its torso and
recurrent core (:mod:`drqn_jax.networks`: the network has one output more
than there are actions — the logits, then the value), its Adam and its
greedy evaluation (:func:`policy_network` for
:func:`~drqn_jax.task.greedy_returns` or :func:`~drqn_jax.agents.drqn.drqn_agent`).

The recurrent state is zeroed before the first step of every episode, in
acting and in the update's unroll (the ``resets`` of each step are the
``done`` flags of the step before), and each minibatch unrolls from the
state its envs had at the rollout's start. Like PureJaxRL, a time limit ends
the advantage's sum as a termination does.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.networks import Network, NetworkConfig, make_network
from drqn_jax.optim import adam, apply_updates, clip_by_global_norm
from drqn_jax.pytree import check_counts, param, pytree_dataclass, tree_where, validate
from drqn_jax.task import Task, make_task

__all__ = [
    "PPOConfig",
    "PPOHyperparams",
    "PPOState",
    "PPOTrainer",
    "gae",
    "make_ppo",
    "policy_network",
    "ppo_loss",
]


@pytree_dataclass
class PPOHyperparams:
    """Traced PPO hyperparameters (PureJaxRL's ppo_rnn defaults for CartPole-v1)."""

    learning_rate: float = param(2.5e-4, low=0.0, low_open=True)
    anneal_lr: int = param(1, low=0, high=1, doc="1: the rate falls linearly to 0")
    adam_eps: float = param(1e-5, low=0.0, low_open=True)
    gamma: float = param(0.99, low=0.0, high=1.0)
    gae_lambda: float = param(0.95, low=0.0, high=1.0)
    clip_eps: float = param(0.2, low=0.0, low_open=True)
    ent_coef: float = param(0.01, low=0.0)
    vf_coef: float = param(0.5, low=0.0)
    max_grad_norm: float = param(0.5, low=0.0, low_open=True)

    def __post_init__(self) -> None:
        validate(self)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Shape-setting PPO settings (hashable; a change recompiles)."""

    env_id: str = "UrbanPedestrians-v0"
    env_overrides: tuple[tuple[str, Any], ...] = ()
    network: NetworkConfig = dataclasses.field(default_factory=NetworkConfig)
    num_envs: int = 4
    num_steps: int = 128
    num_updates: int = 100
    update_epochs: int = 4
    num_minibatches: int = 4

    def __post_init__(self) -> None:
        check_counts(
            self, ("num_envs", "num_steps", "num_updates", "update_epochs", "num_minibatches")
        )
        if self.num_envs % self.num_minibatches:
            raise ValueError(
                f"PPOConfig.num_minibatches = {self.num_minibatches}: must divide num_envs "
                f"({self.num_envs}); a minibatch holds whole env sequences"
            )


class Transition(NamedTuple):
    """One rollout step of N envs (leaves (N, …)); ``reset``: the carry was zeroed
    before it (an episode starts)."""

    obs: Any
    action: jax.Array
    reward: jax.Array
    done: jax.Array
    value: jax.Array
    log_prob: jax.Array
    reset: jax.Array


@pytree_dataclass
class PPOState:
    """Everything a PPO run carries between updates; per-env leaves (N, …);
    ``metrics``: per update, the mean return and count of the episodes that
    ended in its rollout, (num_updates,) each."""

    key: jax.Array
    hparams: PPOHyperparams
    params: Any
    opt_state: Any
    env_state: Any
    obs: Any
    carry: Any
    done: jax.Array
    ep_return: jax.Array
    updates: jax.Array
    metrics: dict[str, jax.Array]


class PPOTrainer(NamedTuple):
    """The pure functions of one PPO configuration (see the module docstring)."""

    config: PPOConfig
    task: Task
    network: Network
    init: Callable[..., PPOState]
    update: Callable[[PPOState], PPOState]
    train: Callable[..., tuple[Any, dict[str, jax.Array]]]


def policy_network(network: Network, num_actions: int) -> Network:
    """``network`` with its value output dropped: ``step`` and ``unroll`` give the
    logits (…, A), whose argmax is the greedy action."""

    def step(params, obs, carry):
        out, carry = network.step(params, obs, carry)
        return out[..., :num_actions], carry

    def unroll(params, obs, carry, resets):
        out, carry = network.unroll(params, obs, carry, resets)
        return out[..., :num_actions], carry

    return network._replace(step=step, unroll=unroll)


def gae(
    value: jax.Array, reward: jax.Array, done: jax.Array, last_value: jax.Array, hp: PPOHyperparams
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimates and value targets, (T, N) each, of a
    rollout's values, rewards and end-of-episode flags (T, N) and the value of
    the state after it (N,)."""

    def back(carry, step):
        advantage, next_value = carry
        v, r, d = step
        delta = r + hp.gamma * next_value * (1.0 - d) - v
        advantage = delta + hp.gamma * hp.gae_lambda * (1.0 - d) * advantage
        return (advantage, v), advantage

    init = (jnp.zeros_like(last_value), last_value)
    _, advantages = jax.lax.scan(
        back, init, (value, reward, done.astype(jnp.float32)), reverse=True
    )
    return advantages, advantages + value


def ppo_loss(
    params: Any,
    network: Network,
    num_actions: int,
    carry: Any,
    batch: Transition,
    advantage: jax.Array,
    target: jax.Array,
    hp: PPOHyperparams,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """The clipped-surrogate loss of a minibatch of whole sequences (T, B, …)
    unrolled from ``carry`` (B, …): actor + vf_coef · clipped value loss −
    ent_coef · entropy, and its parts."""
    out, _ = network.unroll(params, batch.obs, carry, batch.reset)
    logits, value = out[..., :num_actions], out[..., num_actions]
    log_probs = jax.nn.log_softmax(logits)
    log_prob = jnp.take_along_axis(log_probs, batch.action[..., None], axis=-1)[..., 0]
    ratio = jnp.exp(log_prob - batch.log_prob)
    adv = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
    clipped = jnp.clip(ratio, 1.0 - hp.clip_eps, 1.0 + hp.clip_eps)
    actor = -jnp.mean(jnp.minimum(ratio * adv, clipped * adv))
    value_clipped = batch.value + jnp.clip(value - batch.value, -hp.clip_eps, hp.clip_eps)
    critic = 0.5 * jnp.mean(jnp.maximum((value - target) ** 2, (value_clipped - target) ** 2))
    entropy = jnp.mean(-jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1))
    total = actor + hp.vf_coef * critic - hp.ent_coef * entropy
    return total, {"actor": actor, "critic": critic, "entropy": entropy}


def make_ppo(config: PPOConfig | None = None) -> PPOTrainer:
    """Build the pure PPO functions for ``config`` (equal configs: the same functions)."""
    return _make_ppo(PPOConfig() if config is None else config)


@functools.lru_cache(maxsize=16)
def _make_ppo(config: PPOConfig) -> PPOTrainer:
    task = make_task(config.env_id, config.env_overrides)
    n_act, n_env = task.num_actions, config.num_envs
    net_config = task.network(config.network)
    network = make_network(dataclasses.replace(net_config, num_actions=n_act + 1))

    def init(key: jax.Array, hparams: PPOHyperparams | None = None) -> PPOState:
        hp = PPOHyperparams() if hparams is None else hparams
        key, k_net, k_env = jax.random.split(key, 3)
        params = network.init(k_net)
        obs, env_state = jax.vmap(task.reset, (0, None))(
            jax.random.split(k_env, n_env), task.env_params
        )
        return PPOState(
            key=key,
            hparams=hp,
            params=params,
            opt_state=adam(hp.learning_rate, eps=hp.adam_eps).init(params),
            env_state=env_state,
            obs=obs,
            carry=network.initial_carry((n_env,)),
            done=jnp.zeros((n_env,), bool),
            ep_return=jnp.zeros((n_env,), jnp.float32),
            updates=jnp.zeros((), jnp.int32),
            metrics={
                "episode_return": jnp.zeros((config.num_updates,), jnp.float32),
                "episodes": jnp.zeros((config.num_updates,), jnp.int32),
            },
        )

    def update(state: PPOState) -> PPOState:
        carry0 = state.carry
        state, traj, ended = _rollout(config, task, network, state)
        return _learn(config, network, n_act, state, traj, carry0, ended)

    def train(key: jax.Array, hparams: PPOHyperparams | None = None):
        state = init(key, hparams)
        state, _ = jax.lax.scan(lambda s, _: (update(s), None), state, None, config.num_updates)
        return state.params, state.metrics

    return PPOTrainer(config, task, network, init, update, train)


def _restarted(network: Network, state: PPOState) -> Any:
    """The carry (leaves (N, …)) the next step starts from: zeros where the last
    step ended an episode."""
    return tree_where(state.done, network.initial_carry(state.done.shape), state.carry)


def _rollout(config: PPOConfig, task: Task, network: Network, state: PPOState):
    """``num_steps`` steps of the N envs with actions sampled from the policy:
    the moved state, the trajectory (leaves (T, N, …)) and the (sum, count) of
    the returns of the episodes that ended."""
    n_act = task.num_actions

    def step(loop, _):
        state, ret_sum, ret_count = loop
        key, k_act, k_env = jax.random.split(state.key, 3)
        out, carry = network.step(state.params, state.obs, _restarted(network, state))
        logits, value = out[..., :n_act], out[..., n_act]
        action = jax.random.categorical(k_act, logits).astype(jnp.int32)
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[:, None], axis=-1)[:, 0]
        env = jax.vmap(task.step, (0, 0, 0, None))(
            jax.random.split(k_env, config.num_envs), state.env_state, action, task.env_params
        )
        done = env.terminated | env.truncated
        ep_return = state.ep_return + env.reward
        ret_sum = ret_sum + jnp.sum(jnp.where(done, ep_return, 0.0))
        ret_count = ret_count + jnp.sum(done, dtype=jnp.int32)
        traj = Transition(state.obs, action, env.reward, done, value, log_prob, state.done)
        state = state.replace(
            key=key,
            env_state=env.state,
            obs=env.obs,
            carry=carry,
            done=done,
            ep_return=jnp.where(done, 0.0, ep_return),
        )
        return (state, ret_sum, ret_count), traj

    zero = (jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32))
    (state, ret_sum, ret_count), traj = jax.lax.scan(step, (state, *zero), None, config.num_steps)
    return state, traj, (ret_sum, ret_count)


def _learn(
    config: PPOConfig,
    network: Network,
    n_act: int,
    state: PPOState,
    traj: Transition,
    carry0: Any,
    ended: tuple[jax.Array, jax.Array],
) -> PPOState:
    """The update of one rollout: GAE, then epochs of minibatch gradient steps
    (global-norm clip, Adam with the annealed rate), and the update's metrics."""
    hp = state.hparams
    out, _ = network.step(state.params, state.obs, _restarted(network, state))
    advantage, target = gae(traj.value, traj.reward, traj.done, out[..., n_act], hp)
    frac = 1.0 - state.updates.astype(jnp.float32) / config.num_updates
    lr = hp.learning_rate * jnp.where(hp.anneal_lr == 1, frac, 1.0)
    opt = adam(lr, eps=hp.adam_eps)
    per_mb = config.num_envs // config.num_minibatches

    def minibatch(learner, envs):
        params, opt_state = learner
        take = functools.partial(jnp.take, indices=envs, axis=1)
        batch = jax.tree.map(take, traj)
        mb_carry = jax.tree.map(functools.partial(jnp.take, indices=envs, axis=0), carry0)
        grads, _ = jax.grad(ppo_loss, has_aux=True)(
            params, network, n_act, mb_carry, batch, take(advantage), take(target), hp
        )
        grads, _ = clip_by_global_norm(hp.max_grad_norm).update(grads, ())
        updates, opt_state = opt.update(grads, opt_state, params)
        return (apply_updates(params, updates), opt_state), None

    def epoch(loop, _):
        learner, key = loop
        key, k_perm = jax.random.split(key)
        envs = jax.random.permutation(k_perm, config.num_envs)
        learner, _ = jax.lax.scan(minibatch, learner, envs.reshape(-1, per_mb))
        return (learner, key), None

    key, k_epochs = jax.random.split(state.key)
    ((params, opt_state), _), _ = jax.lax.scan(
        epoch, ((state.params, state.opt_state), k_epochs), None, config.update_epochs
    )
    ret_sum, ret_count = ended
    i = state.updates
    mean_return = jnp.where(ret_count > 0, ret_sum / jnp.maximum(ret_count, 1), jnp.nan)
    metrics = {
        "episode_return": state.metrics["episode_return"].at[i].set(mean_return),
        "episodes": state.metrics["episodes"].at[i].set(ret_count),
    }
    return state.replace(
        key=key, params=params, opt_state=opt_state, updates=i + 1, metrics=metrics
    )
