"""Training the DRQN end to end inside one jitted program (paper §V-B, Table II; SPEC §7).

``make_train(config)`` returns a :class:`Trainer` whose functions are pure:

* ``init(key, hparams, env_params) -> TrainState``;
* ``run(state, num_iterations) -> TrainState``: ``lax.scan`` over iterations
  — act ε-greedily with the LSTM carry on N environments, store the step in
  the episode replay, take ``updates_per_step`` Double-DQN gradient steps once
  the replay holds ``learning_starts`` whole episodes, copy the target network
  every ``target_period`` gradient steps. An iteration after the last
  training episode has been recorded changes nothing, so a run split into
  chunks of any size ends bit-identical to a one-shot run;
* ``train(key, hparams=None, env_params=None) -> (params, metrics)``: init,
  then chunks in a ``lax.while_loop`` until ``num_episodes`` episodes are
  recorded, then the choice of the run's agent (below).
  ``jax.jit(jax.vmap(train))(keys)`` runs several seeds at once.

Choosing the run's agent on validation episodes (the project's, not the
paper's, which keeps the last parameters): with ``snapshots`` = K > 0 the
state keeps the online parameters as they were when the recorded episodes
reached k · num_episodes / (K + 1), k = 1 … K. ``validation_metrics(state)``
plays each of these K candidates and the final parameters greedily on
``validation_episodes`` episodes of a key of their own (not the evaluation
key) and measures each one's mean return, collision-free rate and mean speed
(``VALIDATION_METRICS``); once they are stored in ``state.validation``,
``agent_params(state)`` is the candidate that ``select_by`` prefers
(:func:`chosen_candidate`): the best mean return, or the most collision-free
among those no slower than ``select_speed_floor``. Training itself is
unchanged: its every other leaf is bit-identical to a run with K = 0.

ε falls linearly from ``epsilon_start`` to ``epsilon_end`` over the training
episodes (an episode keeps the ε it started with); during the first
``explore_bias_fraction`` of episodes a random action is drawn with
``explore_bias_probs`` (accelerate 0.4, slow_down 0.1, brake 0.1, steer 0.4),
uniformly afterwards. With ``explore_guide`` = g > 0 (the project's, not the
paper's) an exploratory action is, with probability g, the rule-based agent's
(SPEC §6, its default thresholds ``RULE_BASED_GUIDE``) instead: the replay
then holds episodes of braking and waiting for pedestrians, which uniform
random actions rarely produce; learning stays off-policy Q-learning and the
agent acts greedily on its own at evaluation. With ``imitation_weight`` > 0
(the project's) the loss also pulls the greedy action toward the rule-based
agent's in the replayed states — those where it brakes, or all — with DQfD's
large margin (:func:`drqn_jax.loss.large_margin`); the labels are recomputed
from the replay's records of the true state at each gradient step.
The acting LSTM advances on every step and is zeroed when its environment
starts a new episode.

Shape-setting choices live in the hashable :class:`TrainConfig`; the rest
(learning rate, γ, ε schedule, target period, clip mode, …) in the traced
:class:`Hyperparams`, so a sweep can ``vmap`` over them.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.agents.drqn import drqn_agent
from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_action, rule_based_labels
from drqn_jax.env.grid import GridInputs
from drqn_jax.env.params import KMH, EnvParams
from drqn_jax.env.state import BRAKE, NUM_ACTIONS, Observation
from drqn_jax.env.urban import UrbanPedestrians
from drqn_jax.evaluation import episode_keys, run_episodes
from drqn_jax.loss import CLIP_GRAD, CLIP_MODES, sequence_loss
from drqn_jax.networks import Network, NetworkConfig, make_network
from drqn_jax.optim import adam, apply_updates, clip
from drqn_jax.pytree import check_sums_to_one, param, pytree_dataclass, validate
from drqn_jax.registry import make
from drqn_jax.replay import (
    WINDOW_STARTS,
    EpisodeReplay,
    add_transition,
    begin_episodes,
    end_episodes,
    init_replay,
    sample_windows,
)

__all__ = [
    "NOT_LEARNED",
    "REWARD_ALONE",
    "Hyperparams",
    "TrainConfig",
    "TrainState",
    "Trainer",
    "make_train",
    "teacher_label",
    "teachers_of",
]

#: ``fold_in`` index of the draw that picks a guided exploratory action: a
#: stream of its own, so that ``explore_guide = 0`` leaves every other draw,
#: and hence every run, as it was.
GUIDE_STREAM = 1
#: ``fold_in`` index of the validation episodes' key (from the finished state's key).
VALIDATION_STREAM = 2
#: What ``validation_metrics`` measures per candidate, each (K + 1,) float32.
VALIDATION_METRICS = ("return", "collision_free", "speed")
#: Where the imitation term applies (``Hyperparams.imitation_states``).
IMITATION_STATES = ("brake", "all")
IMITATION_ALL = IMITATION_STATES.index("all")
#: How the run's agent is chosen among its candidates (``Hyperparams.select_by``).
SELECT_BY = ("return", "safe")
SELECT_SAFE = SELECT_BY.index("safe")
RULE_BASED_GUIDE = RuleBasedParams()

METRIC_NAMES = (
    "episode_return",
    "length",
    "collision",
    "goal",
    "distance",
    "mean_speed",
    "epsilon",
    "mean_loss",
)


@pytree_dataclass
class Hyperparams:
    """Traced training hyperparameters (paper Table II; SPEC §7)."""

    learning_rate: float = param(1e-3, low=0.0, low_open=True)
    learning_rate_end: float = param(
        1.0,
        low=0.0,
        high=1.0,
        doc="fraction of learning_rate reached at the last training episode, linear in "
        "recorded episodes; 1 keeps it constant (paper)",
    )
    adam_b1: float = param(0.9, low=0.0, high=1.0, high_open=True)
    adam_b2: float = param(0.999, low=0.0, high=1.0, high_open=True)
    adam_eps: float = param(1e-8, low=0.0, low_open=True)
    gamma: float = param(0.9, low=0.0, high=1.0)
    epsilon_start: float = param(1.0, low=0.0, high=1.0)
    epsilon_end: float = param(0.1, low=0.0, high=1.0)
    explore_bias_fraction: float = param(0.1, low=0.0, high=1.0)
    explore_accelerate: float = param(0.4, low=0.0, high=1.0)
    explore_slow_down: float = param(0.1, low=0.0, high=1.0)
    explore_brake: float = param(0.1, low=0.0, high=1.0)
    explore_steer: float = param(0.4, low=0.0, high=1.0)
    explore_guide: float = param(
        0.0,
        low=0.0,
        high=1.0,
        doc="share of exploratory actions taken from the rule-based agent (SPEC §6) "
        "instead of at random; 0 = the paper",
    )
    target_period: int = param(10_000, low=1, doc="gradient steps between target copies")
    learning_starts: int = param(4, low=1, doc="complete episodes in replay before learning")
    clip: int = param("huber", choices=CLIP_MODES)
    window_start: int = param(
        "inside",
        choices=WINDOW_STARTS,
        doc="where a replay window may start: 'inside' the episode (SPEC §7; its last "
        "steps are in fewer windows) or 'anywhere', padded past its end",
    )
    imitation_weight: float = param(
        0.0,
        low=0.0,
        doc="weight of a large-margin term (DQfD) pulling the greedy action toward the "
        "rule-based agent's (SPEC §6) in the replayed states of imitation_states; 0 = the paper",
    )
    imitation_margin: float = param(
        1.0, low=0.0, low_open=True, doc="the margin l by which the expert's Q must lead"
    )
    imitation_states: int = param(
        "brake",
        choices=IMITATION_STATES,
        doc="where the imitation term applies: states where the rule-based agent 'brake's "
        "(a pedestrian in its corridor) or 'all' states",
    )
    imitation_lookahead: float = param(
        7.0,
        low=0.0,
        doc="m: the look-ahead of the rule-based agent whose actions are imitated "
        "(SPEC §6: 7; exploration's guide keeps 7)",
    )
    imitation_corridor_margin: float = param(
        0.5,
        low=0.0,
        doc="m: the corridor margin of the rule-based agent whose actions are imitated "
        "(SPEC §6: 0.5; exploration's guide keeps 0.5)",
    )
    imitation_v_max: float = param(
        15.0 * KMH,
        low=0.0,
        low_open=True,
        doc="m/s: the speed the imitated rule-based agent tracks, within ±1 km/h "
        "(SPEC §6: 15 km/h, the limit; exploration's guide keeps 15 km/h)",
    )
    imitation_horizon: float = param(
        0.0,
        low=0.0,
        doc="s: the imitated rule-based agent also brakes for a pedestrian walking into its "
        "corridor within this time (RuleBasedParams.horizon; 0 = SPEC §6's rule; "
        "exploration's guide keeps 0)",
    )
    value_rescale: int = param(
        0,
        low=0,
        high=1,
        doc="1: the networks learn h(Q), R2D2's value rescaling, with targets "
        "h(r + γ h⁻¹(Q')) (Kapturowski et al. 2019); 0 = the paper",
    )
    select_by: int = param(
        "return",
        choices=SELECT_BY,
        doc="with snapshots > 0, the candidate chosen on the validation episodes: the best "
        "mean 'return', or the 'safe' one (most collision-free at select_speed_floor or faster)",
    )
    select_speed_floor: float = param(
        0.0,
        low=0.0,
        doc="m/s: with select_by = 'safe', candidates slower than this on the validation "
        "episodes are not chosen (none as fast: the final parameters)",
    )

    def __post_init__(self) -> None:
        validate(self)
        check_sums_to_one(
            self,
            ("explore_accelerate", "explore_slow_down", "explore_brake", "explore_steer"),
        )


#: The teacher column of a policy that did not learn (the rule-based agent, …).
NOT_LEARNED = "– (not learned)"
#: The teacher column of an agent that learned from the reward alone.
REWARD_ALONE = "none (reward alone)"


def teacher_label(hp: Hyperparams) -> str:
    """How an agent trained with ``hp`` learned (SPEC §8: every table says it):
    ``"none (reward alone)"``, or the teacher it had — exploration guided by the
    rule-based agent (``explore_guide`` > 0), imitation of its actions
    (``imitation_weight`` > 0), or both."""
    teachers = [
        name
        for name, value in (
            ("guided exploration", hp.explore_guide),
            ("imitation", hp.imitation_weight),
        )
        if float(value) > 0.0
    ]
    return " + ".join(teachers) or REWARD_ALONE


def teachers_of(results: Any) -> str:
    """The teacher column of a row pooling several runs' results (their distinct
    ``teacher`` labels; – for results written before the column existed)."""
    return " / ".join(sorted({r.get("teacher") or "–" for r in results}))


def annealed(hp: Hyperparams, recorded: jax.Array, num_episodes: int) -> Hyperparams:
    """``hp`` with the learning rate of this point of the run: linear from
    ``learning_rate`` (no episode recorded) to ``learning_rate · learning_rate_end``
    (all ``num_episodes`` recorded); exactly ``learning_rate`` when
    ``learning_rate_end`` = 1 (the paper's constant rate)."""
    frac = jnp.minimum(recorded * (1.0 / num_episodes), 1.0)
    scale = 1.0 + (hp.learning_rate_end - 1.0) * frac
    return hp.replace(learning_rate=hp.learning_rate * scale)


@dataclasses.dataclass(frozen=True, eq=False)
class TrainConfig:
    """Shape-setting training settings (hashable; a change recompiles).

    The defaults are the paper's protocol (SPEC §7): one environment, 200
    episodes, replay of 50 episodes, minibatch 32 windows × 8 steps, one
    gradient step per environment step.
    """

    env_id: str = "UrbanPedestrians-v0"
    env_overrides: tuple[tuple[str, Any], ...] = ()
    network: NetworkConfig = dataclasses.field(default_factory=NetworkConfig)
    num_envs: int = 1
    num_episodes: int = 200
    replay_episodes: int = 50
    batch_size: int = 32
    window: int = 8
    n_step: int = dataclasses.field(
        default=1,
        metadata={"doc": "rewards summed per TD target, <= window (1 = the paper)"},
    )
    burn_in: int = dataclasses.field(
        default=0,
        metadata={
            "doc": "steps before each replayed window that only warm the LSTM, without "
            "loss or gradient (R2D2's burn-in; 0 = the paper: the LSTM starts from zeros)"
        },
    )
    updates_per_step: int = 1
    chunk_iterations: int = 1000
    snapshots: int = dataclasses.field(
        default=0,
        metadata={
            "doc": "parameter snapshots kept during training, the agent then chosen among them "
            "and the final parameters on validation episodes (0 = the paper: the final ones)"
        },
    )
    validation_episodes: int = dataclasses.field(
        default=100,
        metadata={"doc": "greedy episodes per candidate when snapshots > 0"},
    )
    hyperparams: Hyperparams = dataclasses.field(default_factory=Hyperparams)

    def __post_init__(self) -> None:
        for name in (
            "num_envs",
            "num_episodes",
            "replay_episodes",
            "batch_size",
            "window",
            "n_step",
            "updates_per_step",
            "chunk_iterations",
            "validation_episodes",
        ):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"TrainConfig.{name} = {value!r}: must be an integer >= 1")
        if not isinstance(self.burn_in, int) or isinstance(self.burn_in, bool) or self.burn_in < 0:
            raise ValueError(f"TrainConfig.burn_in = {self.burn_in!r}: must be an integer >= 0")
        if self.n_step > self.window:
            raise ValueError(
                f"TrainConfig.n_step = {self.n_step}: must be <= window ({self.window}); "
                "an n-step target sums rewards inside one window"
            )
        if not isinstance(self.snapshots, int) or isinstance(self.snapshots, bool):
            raise ValueError(f"TrainConfig.snapshots = {self.snapshots!r}: must be an integer")
        most = self.num_episodes // self.num_envs - 1
        if not 0 <= self.snapshots <= most:
            raise ValueError(
                f"TrainConfig.snapshots = {self.snapshots}: must be in [0, {most}] "
                f"(num_episodes // num_envs - 1): snapshots are taken at least num_envs "
                "episodes apart, the most that end in one iteration"
            )
        if self.replay_episodes < 2 * self.num_envs:
            raise ValueError(
                f"TrainConfig.replay_episodes = {self.replay_episodes}: must be >= 2 × num_envs "
                f"({2 * self.num_envs}); each environment writes its own replay slots"
            )

    def program_key(self) -> tuple:
        """Every field but ``hyperparams``: what a compiled program of ``make_train``'s
        functions depends on when it takes the hyperparameters as arguments (in the
        state, or as ``init``'s), as the runners' programs do. Configs that differ in
        hyperparameter values only share those programs."""
        return tuple(
            getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "hyperparams"
        )

    def __hash__(self) -> int:  # Hyperparams holds arrays: hash the static part only
        return hash(self.program_key())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TrainConfig):
            return NotImplemented
        mine, theirs = jax.tree.leaves(self.hyperparams), jax.tree.leaves(other.hyperparams)
        return self.program_key() == other.program_key() and all(
            bool(jnp.array_equal(a, b)) for a, b in zip(mine, theirs, strict=True)
        )


@pytree_dataclass
class TrainState:
    """Everything a training run carries between iterations (and checkpoints).

    Per-environment leaves have a leading N axis; ``metrics`` holds one
    (num_episodes,) array per name in ``METRIC_NAMES``.
    """

    key: jax.Array
    hparams: Hyperparams
    env_params: EnvParams
    env_state: Any
    obs: Observation
    carry: Any
    online: Any
    target: Any
    opt_state: Any
    replay: EpisodeReplay
    episode: jax.Array  # (N,) int32 index of each env's current episode
    epsilon: jax.Array  # (N,) float32 ε of each env's current episode
    ep_return: jax.Array
    ep_length: jax.Array
    ep_loss_sum: jax.Array
    ep_loss_count: jax.Array
    episodes_started: jax.Array
    recorded: jax.Array  # () int32 training episodes whose metrics are written
    grad_steps: jax.Array
    env_steps: jax.Array
    metrics: dict[str, jax.Array]
    snapshots: Any = None  # [K, ...] online parameters during training; None when K = 0
    validation: Any = None  # {VALIDATION_METRICS: (K + 1,) float32}, NaN until validated

    @property
    def finished(self) -> jax.Array:
        return self.recorded >= self.metrics["length"].shape[-1]


class Trainer(NamedTuple):
    """The pure functions of one training configuration (see the module docstring)."""

    config: TrainConfig
    env: UrbanPedestrians
    env_params: EnvParams
    network: Network
    init: Callable[..., TrainState]
    act: Callable[[TrainState, jax.Array], tuple[jax.Array, Any]]
    run: Callable[[TrainState, int], TrainState]
    train: Callable[..., tuple[Any, dict[str, jax.Array]]]
    gradient_update: Callable[..., tuple[tuple, jax.Array]]
    validation_metrics: Callable[[TrainState], dict[str, jax.Array]]
    agent_params: Callable[[TrainState], Any]


def _tree_where(cond: jax.Array, a: Any, b: Any) -> Any:
    """Leaf-wise ``where`` with ``cond`` (N,) broadcast over trailing axes."""

    def pick(x, y):
        return jnp.where(cond.reshape(cond.shape + (1,) * (x.ndim - cond.ndim)), x, y)

    return jax.tree.map(pick, a, b)


def _small_leaves(state: TrainState) -> TrainState:
    """``state`` with its large buffers (replay, networks, optimiser, metrics) emptied,
    for cheap leaf-wise selection of everything else."""
    return state.replace(
        replay=None, online=None, target=None, opt_state=None, metrics=None, snapshots=None
    )


def chosen_candidate(validation: dict[str, jax.Array], hp: Hyperparams) -> jax.Array:
    """() int32 index of the run's agent among its K + 1 candidates, from their
    validation metrics (``VALIDATION_METRICS``, each (K + 1,)):

    * ``select_by = "return"``: the best mean return;
    * ``select_by = "safe"``: among the candidates whose mean speed is at least
      ``select_speed_floor``, the highest collision-free rate, then the best
      return; the final parameters when none is as fast.

    Of equal candidates, the latest. The final parameters (K) while any metric
    is NaN (not validated yet).
    """
    returns = validation["return"]
    last = returns.shape[-1] - 1
    fast = validation["speed"] >= hp.select_speed_floor
    safest = jnp.max(jnp.where(fast, validation["collision_free"], -jnp.inf))
    safe = fast & (validation["collision_free"] == safest)
    score = jnp.where((hp.select_by != SELECT_SAFE) | safe, returns, -jnp.inf)
    best = last - jnp.argmax(score[::-1])
    unusable = jnp.any(jnp.isnan(jnp.stack(list(validation.values()))))
    unusable |= (hp.select_by == SELECT_SAFE) & ~jnp.any(fast)
    return jnp.where(unusable, last, best).astype(jnp.int32)


def selection(validation: dict[str, Any] | None, hp: Hyperparams) -> dict[str, Any]:
    """Host-side record of a run's choice: ``{}`` without snapshots, else each
    candidate's validation metrics (K + 1 floats each, the last the final
    parameters'; NaN before validation) — ``validation_returns``,
    ``validation_collision_free``, ``validation_speed_kmh`` — and ``selected``
    (:func:`chosen_candidate`, K = the final parameters)."""
    if validation is None:
        return {}
    validation = {name: jnp.asarray(v) for name, v in validation.items()}
    speed_kmh = validation["speed"] * 3.6
    return {
        "validation_returns": [float(r) for r in validation["return"]],
        "validation_collision_free": [float(r) for r in validation["collision_free"]],
        "validation_speed_kmh": [float(v) for v in speed_kmh],
        "selected": int(chosen_candidate(validation, hp)),
    }


def unvalidated(snapshots: int) -> dict[str, jax.Array]:
    """``TrainState.validation`` before validation: NaN for each of the
    ``snapshots`` + 1 candidates and each of ``VALIDATION_METRICS``."""
    return {name: jnp.full((snapshots + 1,), jnp.nan, jnp.float32) for name in VALIDATION_METRICS}


def snapshot_thresholds(config: TrainConfig) -> tuple[int, ...]:
    """Recorded-episode counts at which snapshots 1 … K are taken:
    ``k · num_episodes // (K + 1)``, at least ``num_envs`` apart."""
    k_plus_1 = config.snapshots + 1
    return tuple(k * config.num_episodes // k_plus_1 for k in range(1, k_plus_1))


def make_train(config: TrainConfig | None = None) -> Trainer:
    """Build the pure training functions for ``config``.

    Equal configurations get the same :class:`Trainer` (the same function
    objects), so ``jax.jit`` reuses what it compiled for them.
    """
    return _make_train(TrainConfig() if config is None else config)


@functools.lru_cache(maxsize=32)
def _make_train(config: TrainConfig) -> Trainer:
    env, default_env_params = make(config.env_id, **dict(config.env_overrides))
    network = make_network(dataclasses.replace(config.network, grid_shape=env.static.grid_shape))
    n_env, n_episodes = config.num_envs, config.num_episodes
    max_steps = env.static.max_steps
    n_snapshots = config.snapshots

    def epsilon_of(episode: jax.Array, hp: Hyperparams) -> jax.Array:
        frac = jnp.clip(episode * (1.0 / max(n_episodes - 1, 1)), 0.0, 1.0)
        return (hp.epsilon_start + (hp.epsilon_end - hp.epsilon_start) * frac).astype(jnp.float32)

    def init(
        key: jax.Array, hparams: Hyperparams | None = None, env_params: EnvParams | None = None
    ) -> TrainState:
        hp = config.hyperparams if hparams is None else hparams
        env_params = default_env_params if env_params is None else env_params
        key, k_net, k_env = jax.random.split(key, 3)
        online = network.init(k_net)
        opt = adam(hp.learning_rate, hp.adam_b1, hp.adam_b2, hp.adam_eps)
        obs, env_state = jax.vmap(env.reset, (0, None))(jax.random.split(k_env, n_env), env_params)
        replay = init_replay(config.replay_episodes, max_steps, n_env, env.static)
        replay = begin_episodes(
            replay, jnp.ones((n_env,), bool), GridInputs.of(env_state.ego, env_state.pedestrians)
        )
        episode = jnp.arange(n_env, dtype=jnp.int32)
        zeros_f = jnp.zeros((n_env,), jnp.float32)
        zeros_i = jnp.zeros((n_env,), jnp.int32)
        metrics = {
            name: jnp.zeros((n_episodes,), bool if name in ("collision", "goal") else jnp.float32)
            for name in METRIC_NAMES
        }
        metrics["length"] = jnp.zeros((n_episodes,), jnp.int32)
        snapshots = validation = None
        if n_snapshots:
            snapshots = jax.tree.map(lambda p: jnp.stack([p] * n_snapshots), online)
            validation = unvalidated(n_snapshots)
        return TrainState(
            key=key,
            hparams=hp,
            env_params=env_params,
            env_state=env_state,
            obs=obs,
            carry=network.initial_carry((n_env,)),
            online=online,
            target=online,
            opt_state=opt.init(online),
            replay=replay,
            episode=episode,
            epsilon=epsilon_of(episode, hp),
            ep_return=zeros_f,
            ep_length=zeros_i,
            ep_loss_sum=zeros_f,
            ep_loss_count=zeros_i,
            episodes_started=jnp.asarray(n_env, jnp.int32),
            recorded=jnp.zeros((), jnp.int32),
            grad_steps=jnp.zeros((), jnp.int32),
            env_steps=jnp.zeros((), jnp.int32),
            metrics=metrics,
            snapshots=snapshots,
            validation=validation,
        )

    def act(state: TrainState, key: jax.Array) -> tuple[jax.Array, Any]:
        """ε-greedy actions (N,) and the advanced LSTM carry."""
        hp = state.hparams
        k_explore, k_random = jax.random.split(key)
        q, carry = network.step(state.online, state.obs, state.carry)
        greedy = jnp.argmax(q, axis=-1).astype(jnp.int32)
        biased = state.episode < hp.explore_bias_fraction * n_episodes
        bias = jnp.stack(
            [hp.explore_accelerate, hp.explore_slow_down, hp.explore_brake, hp.explore_steer]
        )
        probs = jnp.where(biased[:, None], bias, 1.0 / NUM_ACTIONS)
        random_action = jax.random.categorical(k_random, jnp.log(probs)).astype(jnp.int32)
        guided = jax.random.uniform(jax.random.fold_in(k_random, GUIDE_STREAM), (n_env,))
        guide_action = jax.vmap(rule_based_action, (0, None, None, None))(
            state.env_state, state.env_params, RULE_BASED_GUIDE, env.static
        )
        random_action = jnp.where(guided < hp.explore_guide, guide_action, random_action)
        explore = jax.random.uniform(k_explore, (n_env,)) < state.epsilon
        return jnp.where(explore, random_action, greedy), carry

    def gradient_update(
        learner: tuple, key: jax.Array, replay: EpisodeReplay, hp: Hyperparams, env_params
    ) -> tuple[tuple, jax.Array]:
        """One Double-DQN gradient step on ``learner`` = (online, target, opt_state,
        grad_steps): sample windows, the rule-based agent's actions in their states
        (the imitation term's expert; weighted 0 unless ``imitation_weight`` > 0), loss
        and gradient, clamp switch, Adam, and the hard target copy every
        ``target_period`` steps. Returns the learner and the loss.
        """
        online, target, opt_state, grad_steps = learner
        opt = adam(hp.learning_rate, hp.adam_b1, hp.adam_b2, hp.adam_eps)
        windows = sample_windows(
            replay,
            key,
            config.batch_size,
            config.window,
            env_params,
            env.static,
            hp.window_start,
            config.burn_in,
        )
        states = jax.tree.map(lambda x: x[:-1], windows.records)  # s_t of each transition
        teacher = RULE_BASED_GUIDE.replace(
            lookahead=hp.imitation_lookahead,
            corridor_margin=hp.imitation_corridor_margin,
            v_max=hp.imitation_v_max,
            horizon=hp.imitation_horizon,
        )
        expert = rule_based_labels(states, env_params, teacher, env.static)
        imitate = (hp.imitation_states == IMITATION_ALL) | (expert == BRAKE)
        (loss, _), grads = jax.value_and_grad(sequence_loss, has_aux=True)(
            online,
            target,
            windows,
            network,
            hp.gamma,
            hp.clip,
            config.n_step,
            expert,
            hp.imitation_weight * imitate.astype(jnp.float32),
            hp.imitation_margin,
            hp.value_rescale,
            config.burn_in,
        )
        clamped, _ = clip(1.0).update(grads, ())
        grads = jax.tree.map(lambda c, g: jnp.where(hp.clip == CLIP_GRAD, c, g), clamped, grads)
        updates, opt_state = opt.update(grads, opt_state, online)
        online = apply_updates(online, updates)
        grad_steps = grad_steps + 1
        copy = grad_steps % hp.target_period == 0
        target = jax.tree.map(lambda o, t: jnp.where(copy, o, t), online, target)
        return (online, target, opt_state, grad_steps), loss

    def learn(
        learner: tuple, replay: EpisodeReplay, hp: Hyperparams, env_params: EnvParams, key
    ) -> tuple[tuple, jax.Array]:
        """``updates_per_step`` gradient steps on ``learner``; the new learner and the
        summed loss.

        Gated by a ``lax.cond`` that takes the replay as a read-only operand and
        returns only the learner: a ``while_loop`` carrying the replay, or a cond
        returning the whole state, makes XLA copy the 13 MB replay every step.
        """

        def update(learner, k):
            return gradient_update(learner, k, replay, hp, env_params)

        keys = jax.random.split(key, config.updates_per_step)
        learner, losses = jax.lax.scan(update, learner, keys)
        return learner, jnp.sum(losses)

    def iteration(state: TrainState) -> TrainState:
        """One vector env step, its storage, learning and episode bookkeeping.

        Once the run has finished (every training episode recorded) the
        iteration changes nothing: small leaves are selected, replay and metric
        writes are masked and learning is gated, so no large buffer is copied.
        """
        live = ~state.finished
        key, k_act, k_env, k_learn = jax.random.split(state.key, 4)
        action, carry = act(state, k_act)
        obs, env_state, reward, terminated, truncated, info = jax.vmap(env.step, (0, 0, 0, None))(
            jax.random.split(k_env, n_env), state.env_state, action, state.env_params
        )
        done = (terminated | truncated) & live
        final = info["final_state"]
        replay = add_transition(
            state.replay,
            action,
            reward,
            terminated,
            GridInputs.of(final.ego, final.pedestrians),
            active=jnp.broadcast_to(live, (n_env,)),
        )
        replay = end_episodes(replay, done)
        replay = begin_episodes(replay, done, GridInputs.of(env_state.ego, env_state.pedestrians))

        can_learn = live & (jnp.sum(replay.complete) >= state.hparams.learning_starts)
        learner = (state.online, state.target, state.opt_state, state.grad_steps)
        (online, target, opt_state, grad_steps), loss_sum = jax.lax.cond(
            can_learn,
            learn,
            lambda learner, *_: (learner, jnp.zeros((), jnp.float32)),
            learner,
            replay,
            annealed(state.hparams, state.recorded, n_episodes),
            state.env_params,
            k_learn,
        )
        n_updates = jnp.where(can_learn, config.updates_per_step, 0)

        # episode bookkeeping
        ep_return = state.ep_return + reward
        ep_length = state.ep_length + 1
        ep_loss_sum = state.ep_loss_sum + loss_sum
        ep_loss_count = state.ep_loss_count + n_updates
        record = done & (state.episode < n_episodes)
        index = jnp.where(record, state.episode, n_episodes)  # out of range: dropped
        duration = ep_length.astype(jnp.float32) * state.env_params.dt
        values = {
            "episode_return": ep_return,
            "length": ep_length,
            "collision": info["collision"],
            "goal": info["goal"],
            "distance": info["distance"],
            "mean_speed": info["distance"] / duration,
            "epsilon": state.epsilon,
            "mean_loss": ep_loss_sum / jnp.maximum(ep_loss_count, 1).astype(jnp.float32),
        }
        metrics = {
            name: state.metrics[name].at[index].set(values[name].astype(buf.dtype), mode="drop")
            for name, buf in state.metrics.items()
        }
        new_episode = state.episodes_started + jnp.cumsum(done.astype(jnp.int32)) - 1
        episode = jnp.where(done, new_episode, state.episode)
        zero_f, zero_i = jnp.zeros_like(ep_return), jnp.zeros_like(ep_length)
        moved = state.replace(
            key=key,
            env_state=env_state,
            obs=obs,
            carry=_tree_where(done, network.initial_carry((n_env,)), carry),
            episode=episode,
            epsilon=jnp.where(done, epsilon_of(episode, state.hparams), state.epsilon),
            ep_return=jnp.where(done, zero_f, ep_return),
            ep_length=jnp.where(done, zero_i, ep_length),
            ep_loss_sum=jnp.where(done, zero_f, ep_loss_sum),
            ep_loss_count=jnp.where(done, zero_i, ep_loss_count),
            episodes_started=state.episodes_started + jnp.sum(done, dtype=jnp.int32),
            recorded=state.recorded + jnp.sum(record, dtype=jnp.int32),
            env_steps=state.env_steps + n_env,
        )
        small = jax.tree.map(
            lambda new, old: jnp.where(live, new, old),
            _small_leaves(moved),
            _small_leaves(state),
        )
        return small.replace(
            replay=replay,
            online=online,
            target=target,
            opt_state=opt_state,
            grad_steps=grad_steps,
            metrics=metrics,
            snapshots=take_snapshot(state.snapshots, online, state.recorded, moved.recorded),
        )

    def take_snapshot(snapshots: Any, online: Any, before: jax.Array, after: jax.Array) -> Any:
        """``snapshots`` with ``online`` written to slot k when the recorded episodes
        cross threshold k in this iteration (at most one: they are ``num_envs`` apart).

        One slot is read and written whether or not it changes, so the cost does
        not grow with K and stays small under ``vmap`` (a ``cond`` would become a
        select of the whole stack).
        """
        if not n_snapshots:
            return snapshots
        thresholds = jnp.asarray(snapshot_thresholds(config), jnp.int32)
        crossed_before = jnp.sum(thresholds <= before)
        crossed = jnp.sum(thresholds <= after)
        slot = jnp.maximum(crossed - 1, 0)
        write = crossed > crossed_before
        return jax.tree.map(
            lambda s, o: s.at[slot].set(jnp.where(write, o, s[slot])), snapshots, online
        )

    def run(state: TrainState, num_iterations: int) -> TrainState:
        """``num_iterations`` iterations; those after the run finished change nothing."""

        def body(state, _):
            return iteration(state), None

        state, _ = jax.lax.scan(body, state, None, length=num_iterations)
        return state

    def train(
        key: jax.Array, hparams: Hyperparams | None = None, env_params: EnvParams | None = None
    ) -> tuple[Any, dict[str, jax.Array]]:
        """A whole training run: final online parameters and per-episode metrics."""
        state = init(key, hparams, env_params)
        state = jax.lax.while_loop(
            lambda s: ~s.finished, lambda s: run(s, config.chunk_iterations), state
        )
        if n_snapshots:
            state = state.replace(validation=validation_metrics(state))
        return agent_params(state), state.metrics

    def candidates(state: TrainState) -> Any:
        """The K snapshots and the final online parameters, stacked: leaves [K + 1, ...]."""
        return jax.tree.map(
            lambda s, o: jnp.concatenate([s, o[None]]), state.snapshots, state.online
        )

    def validation_metrics(state: TrainState) -> dict[str, jax.Array]:
        """``VALIDATION_METRICS``, each (K + 1,) float32: every candidate's mean
        greedy return, share of collision-free episodes and mean speed (m/s, the
        mean over episodes of distance / time, SPEC §8) over ``validation_episodes``
        episodes of ``fold_in(state.key, VALIDATION_STREAM)`` (the same episodes
        for every candidate). Needs K > 0."""
        if not n_snapshots:
            raise ValueError("validation_metrics: the run keeps no snapshots (train.snapshots = 0)")
        keys = episode_keys(
            jax.random.fold_in(state.key, VALIDATION_STREAM), config.validation_episodes
        )

        def measure(params: Any) -> dict[str, jax.Array]:
            episodes = run_episodes(drqn_agent(network, params), keys, env, state.env_params)
            return {
                "return": jnp.mean(episodes.episode_return),
                "collision_free": jnp.mean(1.0 - episodes.collision.astype(jnp.float32)),
                "speed": jnp.mean(episodes.mean_speed),
            }

        return jax.lax.map(measure, candidates(state))

    def agent_params(state: TrainState) -> Any:
        """The run's agent: the final online parameters, or with K > 0 and
        ``state.validation`` filled in, the candidate that ``select_by`` prefers
        (:func:`chosen_candidate`)."""
        if not n_snapshots:
            return state.online
        best = chosen_candidate(state.validation, state.hparams)
        return jax.tree.map(lambda c: c[best], candidates(state))

    return Trainer(
        config=config,
        env=env,
        env_params=default_env_params,
        network=network,
        init=init,
        act=act,
        run=run,
        train=train,
        gradient_update=gradient_update,
        validation_metrics=validation_metrics,
        agent_params=agent_params,
    )
