"""Training a (D)RQN in one jitted program (paper §V-B, Table II; SPEC §7). An iteration
acts ε-greedily on N envs, stores the step in the episode replay, takes ``updates_per_step``
Double-DQN steps once ``learning_starts`` episodes are complete and copies the target every
``target_period`` steps; after the run finished it changes nothing (any chunking, same bits)."""

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.env.state import BRAKE
from drqn_jax.learners.common import (
    SELECT_SAFE,
    LearnerState,
    Trainer,
    epsilon_of,
    init_fields,
    make_trainer,
    per_decision,
    record_episodes,
    take_snapshot,
    unvalidated,
)
from drqn_jax.learners.dqn.loss import CLIP_GRAD, sequence_loss
from drqn_jax.learners.dqn.replay import (
    EpisodeReplay,
    add_transition,
    begin_episodes,
    end_episodes,
    init_replay,
    sample_windows,
)
from drqn_jax.learners.hyperparams import (
    IMITATION_ALL,
    Hyperparams,
    TrainConfig,
    annealed,
    step_share,
)
from drqn_jax.learners.optim import apply_updates, clip, optimizer_of
from drqn_jax.learners.task import Step, Task, make_task
from drqn_jax.networks import Network, make_network
from drqn_jax.programs import cached_program
from drqn_jax.pytree import pytree_dataclass, tree_where

#: ``fold_in`` index of the guided-action draw: its own stream, so that
#: ``explore_guide = 0`` leaves every other draw as it was.
GUIDE_STREAM = 1


@pytree_dataclass
class TrainState(LearnerState):
    """Everything a replay DQN run carries between iterations (and checkpoints)."""

    target: Any
    replay: EpisodeReplay
    epsilon: jax.Array  # (N,) float32 ε of each env's current episode
    snapshots: Any = None  # [K, ...] online parameters during training; None when K = 0
    validation: Any = None  # {Task.validation_metrics: (K + 1,) float32}, NaN until validated


class Learner(NamedTuple):
    """What a gradient step changes: both networks, Adam's state and the step count."""

    online: Any
    target: Any
    opt_state: Any
    grad_steps: jax.Array


def _check_task(config: TrainConfig, task: Task) -> None:
    """Refuse settings the task cannot serve, in one line naming the field."""
    hp = config.hyperparams
    if task.teacher is None:
        for name in ("explore_guide", "imitation_weight"):
            if float(getattr(hp, name)) > 0.0:
                raise ValueError(
                    f"Hyperparams.{name} = {float(getattr(hp, name))}: {config.env_id} has no "
                    "teacher (the rule-based agent drives the paper's env only); use 0"
                )
    if "collision_free" not in task.validation_metrics and int(hp.select_by) == SELECT_SAFE:
        raise ValueError(
            f"Hyperparams.select_by = 'safe': {config.env_id} measures no collisions; use 'return'"
        )


@cached_program
def make_dqn(config: TrainConfig) -> Trainer:
    """The :class:`~drqn_jax.learners.common.Trainer` of an ``algorithm = "dqn"`` config."""
    task = make_task(config.env_id, config.env_overrides)
    _check_task(config, task)
    network = make_network(task.network(config.network))
    act = functools.partial(explore, task, network, config.num_episodes)
    init = functools.partial(_init_state, config, task, network)
    iteration = functools.partial(_iteration, config, task, network, act)
    return make_trainer(config, task, network, init, iteration)


def explore(
    task: Task, network: Network, num_episodes: int, state: TrainState, key: jax.Array
) -> tuple[jax.Array, Any]:
    """ε-greedy actions (N,) int32 and the advanced network carry (paper §V-B). Random
    actions follow the task's biased distribution for the first ``explore_bias_fraction``
    of episodes, then uniform; with ``explore_guide`` = g > 0 (not the paper's) they are
    the rule-based agent's (SPEC §6) with probability g."""
    hp = state.hparams
    n_env = state.episode.shape[0]
    k_explore, k_random = jax.random.split(key)
    q, carry = network.step(state.online, state.obs, state.carry)
    greedy = jnp.argmax(q, axis=-1).astype(jnp.int32)
    biased = state.episode < hp.explore_bias_fraction * num_episodes
    probs = jnp.where(biased[:, None], task.explore_bias(hp), 1.0 / task.num_actions)
    random_action = jax.random.categorical(k_random, jnp.log(probs)).astype(jnp.int32)
    if task.teacher is not None:
        guided = jax.random.uniform(jax.random.fold_in(k_random, GUIDE_STREAM), (n_env,))
        guide_action = jax.vmap(task.teacher.act, (0, None))(state.env_state, state.env_params)
        random_action = jnp.where(guided < hp.explore_guide, guide_action, random_action)
    explore_now = jax.random.uniform(k_explore, (n_env,)) < state.epsilon
    return jnp.where(explore_now, random_action, greedy), carry


def _init_state(
    config: TrainConfig, task: Task, network: Network, key: jax.Array, hp: Hyperparams, env_params
) -> TrainState:
    """N envs reset, their first observations in the replay, fresh networks and Adam."""
    n_env = config.num_envs
    fields = init_fields(config, task, network, key, hp, env_params, ("epsilon",))
    stored = network.initial_carry(()) if config.stored_state else None
    replay = init_replay(config.replay_episodes, task.max_steps, n_env, task.record, stored)
    first = jax.vmap(task.to_record)(fields["obs"], fields["env_state"])
    replay = begin_episodes(
        replay, jnp.ones((n_env,), bool), first, network.initial_carry((n_env,))
    )
    snapshots = validation = None
    if config.snapshots:
        snapshots = jax.tree.map(lambda p: jnp.stack([p] * config.snapshots), fields["online"])
        validation = unvalidated(config.snapshots, task.validation_metrics)
    return TrainState(
        **fields,
        target=fields["online"],
        replay=replay,
        epsilon=epsilon_of(fields["episode"], hp, config.num_episodes),
        snapshots=snapshots,
        validation=validation,
    )


def _store(
    task: Task, network: Network, replay: EpisodeReplay, action, step: Step, carry, done, live
) -> EpisodeReplay:
    """The replay with one vector step stored: transitions, ended and begun episodes."""
    replay = add_transition(
        replay,
        action,
        step.reward,
        step.terminated,
        step.final,
        active=jnp.broadcast_to(live, done.shape),
        next_carry=carry,
    )
    replay = end_episodes(replay, done)
    first = jax.vmap(task.to_record)(step.obs, step.state)
    return begin_episodes(replay, done, first, network.initial_carry(done.shape))


def _iteration(
    config: TrainConfig, task: Task, network: Network, act: Callable, state: TrainState
) -> TrainState:
    """One vector env step, its storage, learning and bookkeeping; once finished it
    changes nothing (writes masked, learning gated, no large buffer copied)."""
    n_env = config.num_envs
    live = ~state.finished
    key, k_act, k_env, k_learn = jax.random.split(state.key, 4)
    action, carry = act(state, k_act)
    step = jax.vmap(task.step, (0, 0, 0, None))(
        jax.random.split(k_env, n_env), state.env_state, action, state.env_params
    )
    done = (step.terminated | step.truncated) & live
    replay = _store(task, network, state.replay, action, step, carry, done, live)

    can_learn = live & (jnp.sum(replay.complete) >= state.hparams.learning_starts)
    steps = step_share(config, state.env_steps)
    learner = Learner(state.online, state.target, state.opt_state, state.grad_steps)
    learner, loss_sum = jax.lax.cond(
        can_learn,
        functools.partial(learn, config, task, network),
        lambda learner, *_: (learner, jnp.zeros((), jnp.float32)),
        learner,
        replay,
        annealed(state.hparams, state.recorded, config.num_episodes, steps),
        state.env_params,
        k_learn,
    )
    n_updates = jnp.where(can_learn, config.updates_per_step, 0)
    extra = {"epsilon": state.epsilon}
    moved, metrics = record_episodes(
        task, config.num_episodes, state, step, done, loss_sum, n_updates, extra
    )
    moved = moved.replace(
        key=key,
        carry=tree_where(done, network.initial_carry((n_env,)), carry),
        epsilon=jnp.where(
            done,
            epsilon_of(moved.episode, state.hparams, config.num_episodes, steps),
            state.epsilon,
        ),
    )
    large = {  # written masked or gated above; the small leaves are selected by ``live``
        "replay": replay,
        "online": learner.online,
        "target": learner.target,
        "opt_state": learner.opt_state,
        "metrics": metrics,
        "snapshots": take_snapshot(
            config, state.snapshots, learner.online, state.recorded, moved.recorded
        ),
    }
    none = dict.fromkeys(large)
    small = jax.tree.map(
        lambda new, old: jnp.where(live, new, old), moved.replace(**none), state.replace(**none)
    )
    return small.replace(**large, grad_steps=learner.grad_steps)


def _imitation(task: Task, windows: Any, hp: Hyperparams, env_params: Any) -> tuple:
    """Expert actions and imitation weights (W, B), or (None, None) without a teacher."""
    if task.teacher is None:
        return None, None
    states = jax.tree.map(lambda x: x[:-1], windows.records)  # s_t of each transition
    expert = task.teacher.labels(states, env_params, hp)
    imitate = (hp.imitation_states == IMITATION_ALL) | (expert == BRAKE)
    return expert, hp.imitation_weight * imitate.astype(jnp.float32)


def gradient_update(
    config: TrainConfig,
    task: Task,
    network: Network,
    learner: Learner | tuple,
    key: jax.Array,
    replay: EpisodeReplay,
    hp: Hyperparams,
    env_params: Any,
) -> tuple[Learner, jax.Array]:
    """One Double-DQN gradient step on ``learner``; the new learner and the () loss."""
    opt = optimizer_of(config, hp)

    def observe(records: Any, last_action: jax.Array) -> Any:
        return task.observe(records, last_action, env_params)

    windows = sample_windows(
        replay, key, config.batch_size, config.window, observe, hp.window_start, config.burn_in
    )
    expert, weight = _imitation(task, windows, hp, env_params)
    (loss, _), grads = jax.value_and_grad(sequence_loss, has_aux=True)(
        learner.online,
        learner.target,
        windows,
        network,
        per_decision(hp, task),
        config.n_step,
        expert,
        weight,
        config.burn_in,
    )
    clamped = clip(grads, 1.0)
    grads = jax.tree.map(lambda c, g: jnp.where(hp.clip == CLIP_GRAD, c, g), clamped, grads)
    updates, opt_state = opt.update(grads, learner.opt_state, learner.online)
    online = apply_updates(learner.online, updates)
    grad_steps = learner.grad_steps + 1
    copy = grad_steps % hp.target_period == 0
    target = jax.tree.map(lambda o, t: jnp.where(copy, o, t), online, learner.target)
    return Learner(online, target, opt_state, grad_steps), loss


def learn(
    config: TrainConfig,
    task: Task,
    network: Network,
    learner: Learner,
    replay: EpisodeReplay,
    hp: Hyperparams,
    env_params: Any,
    key: jax.Array,
) -> tuple[Learner, jax.Array]:
    """``updates_per_step`` gradient steps: the new learner and the summed loss (the replay a
    read-only operand of the gating ``lax.cond``: carried, XLA would copy it every step)."""

    def update(learner, k):
        return gradient_update(config, task, network, learner, k, replay, hp, env_params)

    keys = jax.random.split(key, config.updates_per_step)
    learner, losses = jax.lax.scan(update, learner, keys)
    return learner, jnp.sum(losses)
