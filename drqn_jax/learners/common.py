"""What the learners share (paper §V-B; SPEC §7): the :class:`Trainer`, the state's start,
per-episode bookkeeping of N envs (metrics at each episode's index of (num_episodes,)
buffers), the ε schedule, the on-policy rollout and minibatch epochs, and the run's agent
among ``snapshots`` (K snapshots and the final parameters, chosen by ``select_by``)."""

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.evaluation import episode_keys
from drqn_jax.learners.hyperparams import SELECT_BY, Hyperparams, TrainConfig, annealed, step_share
from drqn_jax.learners.optim import apply_updates, clip_by_global_norm, optimizer_of
from drqn_jax.learners.task import Step, Task
from drqn_jax.networks import Network
from drqn_jax.pytree import pytree_dataclass, tree_where


class Trainer(NamedTuple):
    """The pure functions of one training configuration: ``init``, ``run(state, n)`` (no-ops
    once finished: any chunking ends bit-identical), ``train`` -> (agent params, metrics),
    ``validation_metrics``, ``agent_params``; every state is a :class:`LearnerState`."""

    config: Any
    task: Any
    network: Any
    init: Callable[..., Any]
    run: Callable[[Any, int], Any]
    train: Callable[..., tuple[Any, dict[str, jax.Array]]]
    validation_metrics: Callable[[Any], dict[str, jax.Array]]
    agent_params: Callable[[Any], Any]


def make_trainer(
    config: Any,
    task: Any,
    network: Any,
    init: Callable[..., Any],
    iteration: Callable[[Any], Any],
) -> Trainer:
    """A learner's :class:`Trainer` from its ``iteration(state)`` (a no-op
    once finished) and ``init(key, hp, env_params)``, whose last two default to the
    config's and the task's."""

    def run(state: Any, num_iterations: int) -> Any:
        return jax.lax.scan(lambda s, _: (iteration(s), None), state, None, num_iterations)[0]

    def init_state(key: jax.Array, hparams: Any = None, env_params: Any = None) -> Any:
        hp = config.hyperparams if hparams is None else hparams
        return init(key, hp, task.env_params if env_params is None else env_params)

    validation_metrics = functools.partial(candidate_metrics, config, task, network)
    agent_params = functools.partial(run_agent, config)

    def train(key: jax.Array, hparams: Any = None, env_params: Any = None):
        """Init, chunks in a ``lax.while_loop`` until finished, then the agent's choice:
        ``(agent params, metrics)``; ``vmap`` it over seeds."""
        state = init_state(key, hparams, env_params)
        state = jax.lax.while_loop(
            lambda s: ~s.finished, lambda s: run(s, config.chunk_iterations), state
        )
        if config.snapshots:
            state = state.replace(validation=validation_metrics(state))
        return agent_params(state), state.metrics

    return Trainer(
        config=config,
        task=task,
        network=network,
        init=init_state,
        run=run,
        train=train,
        validation_metrics=validation_metrics,
        agent_params=agent_params,
    )


#: Per-episode metrics of every learner and task; a learner adds its own (the
#: DQN: ε), a task its own (the paper's env: collision, goal, distance, speed).
BASE_METRICS = ("episode_return", "length", "mean_loss")


def per_decision(hp: Hyperparams, task: Task) -> Hyperparams:
    """``hp`` with the discount and the λs of one decision of k = ``task.decision_steps``
    ticks: their per-tick values ** k, so ``train.gamma`` keeps its horizon in seconds
    (SPEC §7); ``hp`` itself for k = 1."""
    k = task.decision_steps
    if k == 1:
        return hp
    return hp.replace(gamma=hp.gamma**k, gae_lambda=hp.gae_lambda**k, q_lambda=hp.q_lambda**k)


def init_fields(
    config: TrainConfig,
    task: Task,
    network: Network,
    key: jax.Array,
    hp: Hyperparams,
    env_params: Any,
    extra: tuple[str, ...] = (),
) -> dict[str, Any]:
    """The fields every learner's state starts with: N envs reset, fresh ``online``
    parameters and optimiser, zero carries, env i in episode i, running sums (N,) at
    zero and empty metrics (``extra``: the learner's own)."""
    n_env = config.num_envs
    key, k_net, k_env = jax.random.split(key, 3)
    online = network.init(k_net)
    obs, env_state = jax.vmap(task.reset, (0, None))(jax.random.split(k_env, n_env), env_params)
    zeros_f, zeros_i = jnp.zeros((n_env,), jnp.float32), jnp.zeros((n_env,), jnp.int32)
    dtypes = dict.fromkeys((*BASE_METRICS, *extra), jnp.float32)
    dtypes = {**dtypes, "length": jnp.int32, **dict(task.metrics)}
    return {
        "key": key,
        "hparams": hp,
        "env_params": env_params,
        "env_state": env_state,
        "obs": obs,
        "carry": network.initial_carry((n_env,)),
        "online": online,
        "opt_state": optimizer_of(config, hp).init(online),
        "episode": jnp.arange(n_env, dtype=jnp.int32),
        "ep_return": zeros_f,
        "ep_length": zeros_i,
        "ep_loss_sum": zeros_f,
        "ep_loss_count": zeros_i,
        "episodes_started": jnp.asarray(n_env, jnp.int32),
        "recorded": jnp.zeros((), jnp.int32),
        "grad_steps": jnp.zeros((), jnp.int32),
        "env_steps": jnp.zeros((), jnp.int32),
        "step_budget": jnp.asarray(config.num_env_steps, jnp.int32),
        "metrics": {name: jnp.zeros((config.num_episodes,), t) for name, t in dtypes.items()},
    }


def record_episodes(
    task: Task,
    num_episodes: int,
    state: Any,
    step: Step,
    done: jax.Array,
    loss_sum: jax.Array,
    n_updates: jax.Array,
    extra: dict[str, jax.Array] | None = None,
) -> tuple[Any, dict[str, jax.Array]]:
    """The bookkeeping of one vector env step (leaves (N,)): ``done`` (N,) episodes
    are written (with ``extra``, e.g. ε) and take the next free index. Returns the
    moved state and the metrics."""
    ep_return = state.ep_return + step.reward
    ep_length = state.ep_length + 1
    ep_loss_sum = state.ep_loss_sum + loss_sum
    ep_loss_count = state.ep_loss_count + n_updates
    record = done & (state.episode < num_episodes)
    index = jnp.where(record, state.episode, num_episodes)  # out of range: dropped
    values = {
        "episode_return": ep_return,
        "length": ep_length,
        **task.episode_metrics(step, state.env_params),
        **(extra or {}),
        "mean_loss": ep_loss_sum / jnp.maximum(ep_loss_count, 1).astype(jnp.float32),
    }
    metrics = {
        name: state.metrics[name].at[index].set(values[name].astype(buf.dtype), mode="drop")
        for name, buf in state.metrics.items()
    }
    new_episode = state.episodes_started + jnp.cumsum(done.astype(jnp.int32)) - 1
    zero_f, zero_i = jnp.zeros_like(ep_return), jnp.zeros_like(ep_length)
    moved = state.replace(
        env_state=step.state,
        obs=step.obs,
        episode=jnp.where(done, new_episode, state.episode),
        ep_return=jnp.where(done, zero_f, ep_return),
        ep_length=jnp.where(done, zero_i, ep_length),
        ep_loss_sum=jnp.where(done, zero_f, ep_loss_sum),
        ep_loss_count=jnp.where(done, zero_i, ep_loss_count),
        episodes_started=state.episodes_started + jnp.sum(done, dtype=jnp.int32),
        recorded=state.recorded + jnp.sum(record, dtype=jnp.int32),
        env_steps=state.env_steps + done.shape[0],
    )
    return moved, metrics


def epsilon_of(
    episode: jax.Array, hp: Hyperparams, num_episodes: int, steps: jax.Array | None = None
) -> jax.Array:
    """float32 ε of training ``episode``: linear from ``epsilon_start`` to ``epsilon_end``
    over the ``epsilon_fraction`` share (or ``steps``' budget share, the further)."""
    frac = episode * (1.0 / max(num_episodes - 1, 1))
    if steps is not None:
        frac = jnp.maximum(frac, steps)
    frac = jnp.clip(frac / hp.epsilon_fraction, 0.0, 1.0)
    return (hp.epsilon_start + (hp.epsilon_end - hp.epsilon_start) * frac).astype(jnp.float32)


def restarted(network: Network, state: Any) -> Any:
    """``state.carry`` (N, …), zeroed where ``state.done`` (N,)."""
    return tree_where(state.done, network.initial_carry(state.done.shape), state.carry)


#: ``policy(state, key) -> (actions (N,) int32, carry, acted, extra)``; ``acted``:
#: its transition fields, ``extra``: per-env values written with an episode, or None.
Policy = Callable[[Any, jax.Array], tuple[jax.Array, Any, dict[str, Any], Any]]


def rollout(
    config: TrainConfig, task: Task, policy: Policy, transition: Callable[..., Any], state: Any
) -> tuple[Any, Any]:
    """``rollout_steps`` steps by ``policy``: the moved state and a ``transition``
    (T, N, …) of ``obs``, ``action``, ``reward``, ``done``, ``reset`` and ``acted``."""
    zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)

    def step(state, _):
        key, k_act, k_env = jax.random.split(state.key, 3)
        action, carry, acted, extra = policy(state, k_act)
        env = jax.vmap(task.step, (0, 0, 0, None))(
            jax.random.split(k_env, config.num_envs), state.env_state, action, state.env_params
        )
        done = env.terminated | env.truncated
        traj = transition(
            obs=state.obs, action=action, reward=env.reward, done=done, reset=state.done, **acted
        )
        moved, metrics = record_episodes(
            task, config.num_episodes, state, env, done, zero_f, zero_i, extra
        )
        return moved.replace(key=key, carry=carry, done=done, metrics=metrics), traj

    return jax.lax.scan(step, state, None, config.rollout_steps)


def minibatch_epochs(
    config: TrainConfig,
    state: Any,
    loss_of: Callable[[Any, Any, Any], tuple[jax.Array, jax.Array]],
    sequences: Any,
    per_env: Any,
) -> Any:
    """``update_epochs`` passes of ``num_minibatches`` random minibatches of whole env
    sequences at the annealed rate; ``loss_of(params, sequences (T, N / M, …), per_env
    (N / M, …))`` -> (loss, loss), its gradients clipped to ``max_grad_norm``. The
    mean loss joins every running episode's."""
    hp = state.hparams
    steps = step_share(config, state.env_steps)
    lr = annealed(hp, state.recorded, config.num_episodes, steps).learning_rate
    opt = optimizer_of(config, hp, lr)
    per_mb = config.num_envs // config.num_minibatches

    def minibatch(learner, envs):
        params, opt_state = learner
        seqs = jax.tree.map(functools.partial(jnp.take, indices=envs, axis=1), sequences)
        starts = jax.tree.map(functools.partial(jnp.take, indices=envs, axis=0), per_env)
        grads, loss = jax.grad(loss_of, has_aux=True)(params, seqs, starts)
        grads = clip_by_global_norm(grads, hp.max_grad_norm)
        updates, opt_state = opt.update(grads, opt_state, params)
        return (apply_updates(params, updates), opt_state), loss

    def epoch(loop, _):
        learner, key = loop
        key, k_perm = jax.random.split(key)
        envs = jax.random.permutation(k_perm, config.num_envs)
        learner, losses = jax.lax.scan(minibatch, learner, envs.reshape(-1, per_mb))
        return (learner, key), losses

    key, k_epochs = jax.random.split(state.key)
    ((params, opt_state), _), losses = jax.lax.scan(
        epoch, ((state.online, state.opt_state), k_epochs), None, config.update_epochs
    )
    return state.replace(
        key=key,
        online=params,
        opt_state=opt_state,
        ep_loss_sum=state.ep_loss_sum + jnp.mean(losses),
        ep_loss_count=state.ep_loss_count + 1,
        grad_steps=state.grad_steps + config.update_epochs * config.num_minibatches,
    )


@dataclasses.dataclass(frozen=True)
class LearnerState:
    """The fields every learner's state carries between iterations (and checkpoints):
    per-env leaves (N, …), ``online`` the network's parameters, ``metrics``
    (num_episodes,) per name; ``finished`` once either budget is met."""

    key: jax.Array
    hparams: Hyperparams
    env_params: Any
    env_state: Any
    obs: Any
    carry: Any
    online: Any
    opt_state: Any
    episode: jax.Array  # (N,) int32 index of each env's current episode
    ep_return: jax.Array
    ep_length: jax.Array
    ep_loss_sum: jax.Array
    ep_loss_count: jax.Array
    episodes_started: jax.Array
    recorded: jax.Array  # () int32 training episodes whose metrics are written
    grad_steps: jax.Array
    env_steps: jax.Array
    step_budget: jax.Array  # () int32 TrainConfig.num_env_steps (0: none)
    metrics: dict[str, jax.Array]

    @property
    def finished(self) -> jax.Array:
        """() bool: all ``num_episodes`` recorded, or ``step_budget`` (0: none) steps taken."""
        by_steps = (self.step_budget > 0) & (self.env_steps >= self.step_budget)
        return (self.recorded >= self.metrics["length"].shape[-1]) | by_steps


@pytree_dataclass
class OnPolicyState(LearnerState):
    """A PPO or PQN run's state; ``done`` (N,) restarts the carry; ``memory``: the
    transitions (W, N, …) the next update trains again before its rollout, or None."""

    done: jax.Array
    memory: Any = None
    #: The protocol's candidates' validation metrics: none, no snapshot is selected.
    validation: ClassVar[None] = None


def make_on_policy(
    config: TrainConfig,
    task: Task,
    network: Network,
    agent: Network,
    policy: Policy,
    transition: Callable[..., Any],
    learn: Callable[[OnPolicyState, Any, Any], OnPolicyState],
    extra: tuple[str, ...] = (),
    memory: Callable[[dict[str, Any]], Any] | None = None,
) -> Trainer:
    """The :class:`Trainer` of a learner without a replay (PPO, PQN): each update a
    :func:`rollout` by ``policy`` into ``transition``s, then ``learn(state, traj,
    carry before the rollout)``; ``agent`` is the network the run's agent acts with,
    ``extra`` the learner's own metrics, ``memory(fields)`` the initial memory."""

    def init(key: jax.Array, hp: Hyperparams, env_params: Any) -> OnPolicyState:
        fields = init_fields(config, task, network, key, hp, env_params, extra)
        done = jnp.zeros((config.num_envs,), bool)
        return OnPolicyState(**fields, done=done, memory=None if memory is None else memory(fields))

    def update(state: OnPolicyState) -> OnPolicyState:
        carry0 = state.carry
        state, traj = rollout(config, task, policy, transition, state)
        return learn(state, traj, carry0)

    def iteration(state: OnPolicyState) -> OnPolicyState:
        return jax.lax.cond(state.finished, lambda s: s, update, state)

    return make_trainer(config, task, agent, init, iteration)


#: ``fold_in`` index of the validation episodes' key (from the finished state's key).
VALIDATION_STREAM = 2
SELECT_SAFE = SELECT_BY.index("safe")


def chosen_candidate(validation: dict[str, jax.Array], hp: Hyperparams) -> jax.Array:
    """() int32 index of the run's agent among K + 1 candidates (metrics (K + 1,)): the best
    return, or with ``"safe"`` the most collision-free at ``select_speed_floor`` or faster.
    Ties: the latest; any NaN, or none fast enough: the final parameters (K)."""
    returns = validation["return"]
    last = returns.shape[-1] - 1
    unusable = jnp.any(jnp.isnan(jnp.stack(list(validation.values()))))
    if "speed" not in validation:  # a task that measures returns only: select_by "return"
        return jnp.where(unusable, last, last - jnp.argmax(returns[::-1])).astype(jnp.int32)
    fast = validation["speed"] >= hp.select_speed_floor
    safest = jnp.max(jnp.where(fast, validation["collision_free"], -jnp.inf))
    safe = fast & (validation["collision_free"] == safest)
    score = jnp.where((hp.select_by != SELECT_SAFE) | safe, returns, -jnp.inf)
    best = last - jnp.argmax(score[::-1])
    unusable |= (hp.select_by == SELECT_SAFE) & ~jnp.any(fast)
    return jnp.where(unusable, last, best).astype(jnp.int32)


def selection(validation: dict[str, Any] | None, hp: Hyperparams) -> dict[str, Any]:
    """Host-side record of a run's choice: ``{}`` without snapshots, else the
    candidates' ``validation_*`` lists (K + 1 floats) and ``selected``."""
    if validation is None:
        return {}
    validation = {name: jnp.asarray(v) for name, v in validation.items()}
    out = {"validation_returns": [float(r) for r in validation["return"]]}
    if "collision_free" in validation:
        out["validation_collision_free"] = [float(r) for r in validation["collision_free"]]
        out["validation_speed_kmh"] = [float(v) for v in validation["speed"] * 3.6]
    return {**out, "selected": int(chosen_candidate(validation, hp))}


def unvalidated(snapshots: int, names: tuple[str, ...]) -> dict:
    """``TrainState.validation`` before validation: NaN (snapshots + 1,) per name of
    ``Task.validation_metrics``."""
    return {name: jnp.full((snapshots + 1,), jnp.nan, jnp.float32) for name in names}


def snapshot_thresholds(config: TrainConfig) -> tuple[int, ...]:
    """Recorded-episode counts at which snapshots 1 … K are taken:
    ``k · num_episodes // (K + 1)``, at least ``num_envs`` apart."""
    k_plus_1 = config.snapshots + 1
    return tuple(k * config.num_episodes // k_plus_1 for k in range(1, k_plus_1))


def take_snapshot(
    config: TrainConfig, snapshots: Any, online: Any, before: jax.Array, after: jax.Array
) -> Any:
    """``snapshots`` (leaves [K, ...]) with ``online`` in slot k when the recorded
    episodes cross threshold k between ``before`` and ``after``. One slot is always
    rewritten, so the cost under ``vmap`` does not grow with K."""
    if not config.snapshots:
        return snapshots
    thresholds = jnp.asarray(snapshot_thresholds(config), jnp.int32)
    crossed_before = jnp.sum(thresholds <= before)
    crossed = jnp.sum(thresholds <= after)
    slot = jnp.maximum(crossed - 1, 0)
    write = crossed > crossed_before
    return jax.tree.map(
        lambda s, o: s.at[slot].set(jnp.where(write, o, s[slot])), snapshots, online
    )


def candidates(snapshots: Any, online: Any) -> Any:
    """The K snapshots and the final online parameters, stacked: leaves [K + 1, ...]."""
    return jax.tree.map(lambda s, o: jnp.concatenate([s, o[None]]), snapshots, online)


def candidate_metrics(config: TrainConfig, task: Any, network: Any, state: Any) -> dict:
    """The task's validation metrics (K + 1,) float32 of a finished run's candidates,
    on the same ``validation_episodes`` for each (SPEC §8). Needs K > 0."""
    if not config.snapshots:
        raise ValueError("validation_metrics: the run keeps no snapshots (train.snapshots = 0)")
    keys = episode_keys(
        jax.random.fold_in(state.key, VALIDATION_STREAM), config.validation_episodes
    )

    def measure(params: Any) -> dict[str, jax.Array]:
        return task.validate(network, params, keys, state.env_params)

    return jax.lax.map(measure, candidates(state.snapshots, state.online))


def run_agent(config: TrainConfig, state: Any) -> Any:
    """The run's agent: the final parameters, or with K > 0 the chosen candidate."""
    if not config.snapshots:
        return state.online
    best = chosen_candidate(state.validation, state.hparams)
    return jax.tree.map(lambda c: c[best], candidates(state.snapshots, state.online))
