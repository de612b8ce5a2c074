"""What a training run is configured with (paper Table II; SPEC §7): the traced
:class:`Hyperparams` (a sweep ``vmap``s over them), the shape-setting
:class:`TrainConfig` (hashable; a change recompiles), and how a trained agent is
named in results tables (:func:`teacher_label`, :func:`agent_name`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.env.params import KMH
from drqn_jax.learners.optim import OPTIMIZERS
from drqn_jax.networks import NetworkConfig
from drqn_jax.pytree import check_counts, check_sums_to_one, param, pytree_dataclass, validate

__all__ = [
    "ALGORITHMS",
    "CLIP_MODES",
    "IMITATION_STATES",
    "LEARNED_AGENTS",
    "NOT_LEARNED",
    "REWARD_ALONE",
    "SELECT_BY",
    "WINDOW_STARTS",
    "Hyperparams",
    "TrainConfig",
    "agent_name",
    "annealed",
    "has_teacher",
    "step_share",
    "teacher_label",
    "teachers_of",
]

#: The replay DQN's TD loss (``Hyperparams.clip``): Huber, or the squared error
#: with its gradient clipped.
CLIP_MODES = ("huber", "grad")
#: Where a replay window may start (``Hyperparams.window_start``).
WINDOW_STARTS = ("inside", "anywhere")
#: Where the imitation term applies (``Hyperparams.imitation_states``).
IMITATION_STATES = ("brake", "all")
IMITATION_ALL = IMITATION_STATES.index("all")
#: How the run's agent is chosen among its candidates (``Hyperparams.select_by``).
SELECT_BY = ("return", "safe")
#: The learners (``TrainConfig.algorithm``).
ALGORITHMS = ("dqn", "ppo", "pqn")
#: The learners without a replay: each update learns from a rollout of every env.
ON_POLICY = ("ppo", "pqn")


@pytree_dataclass
class Hyperparams:
    """Traced training hyperparameters (paper Table II; SPEC §7)."""

    learning_rate: float = param(1e-3, low=0.0, low_open=True)
    learning_rate_end: float = param(
        1.0, low=0.0, high=1.0, doc="learning_rate's fraction at the end (linear); 1 = the paper"
    )
    adam_b1: float = param(0.9, low=0.0, high=1.0, high_open=True)
    adam_b2: float = param(0.999, low=0.0, high=1.0, high_open=True)
    adam_eps: float = param(1e-8, low=0.0, low_open=True)
    gamma: float = param(0.9, low=0.0, high=1.0)
    epsilon_start: float = param(1.0, low=0.0, high=1.0)
    epsilon_end: float = param(0.1, low=0.0, high=1.0)
    epsilon_fraction: float = param(
        1.0,
        low=0.0,
        high=1.0,
        low_open=True,
        doc="share of the training episodes over which ε falls to epsilon_end, then "
        "stays (SB3's exploration_fraction); 1 = the paper: over all of them",
    )
    explore_bias_fraction: float = param(0.1, low=0.0, high=1.0)
    explore_accelerate: float = param(0.4, low=0.0, high=1.0)
    explore_slow_down: float = param(0.1, low=0.0, high=1.0)
    explore_brake: float = param(0.1, low=0.0, high=1.0)
    explore_steer: float = param(0.4, low=0.0, high=1.0)
    explore_guide: float = param(
        0.0, low=0.0, high=1.0, doc="rule-based agent's share of exploratory actions; 0 = the paper"
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
        7.0, low=0.0, doc="m: the imitated rule-based agent's look-ahead (SPEC §6: 7)"
    )
    imitation_corridor_margin: float = param(
        0.5, low=0.0, doc="m: the imitated rule-based agent's corridor margin (SPEC §6: 0.5)"
    )
    imitation_v_max: float = param(
        15.0 * KMH,
        low=0.0,
        low_open=True,
        doc="m/s: the speed the imitated rule-based agent tracks (SPEC §6: 15 km/h)",
    )
    imitation_horizon: float = param(
        0.0,
        low=0.0,
        doc="s: the imitated rule-based agent also brakes for a pedestrian walking into its "
        "corridor within this time (RuleBasedParams.horizon; 0 = SPEC §6's rule)",
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
    gae_lambda: float = param(
        0.95, low=0.0, high=1.0, doc="ppo: λ of the generalised advantage estimates"
    )
    q_lambda: float = param(
        0.95, low=0.0, high=1.0, doc="pqn: λ of the Q(λ) targets (purejaxql: 0.95)"
    )
    reward_scale: float = param(
        1.0,
        low=0.0,
        low_open=True,
        doc="pqn: rewards are multiplied by this in the Q(λ) targets (purejaxql's "
        "REW_SCALE; the metrics keep the env's reward); 1 for the other learners",
    )
    clip_eps: float = param(
        0.2, low=0.0, low_open=True, doc="ppo: clip range of the probability ratio and the value"
    )
    ent_coef: float = param(0.01, low=0.0, doc="ppo: weight of the policy's entropy bonus")
    vf_coef: float = param(0.5, low=0.0, doc="ppo: weight of the value loss")
    max_grad_norm: float = param(
        0.5,
        low=0.0,
        low_open=True,
        doc="ppo, pqn: gradients are scaled down to this global norm (PureJaxRL: 0.5)",
    )

    def __post_init__(self) -> None:
        validate(self)
        check_sums_to_one(
            self, ("explore_accelerate", "explore_slow_down", "explore_brake", "explore_steer")
        )


#: The teacher column of a policy that did not learn (the rule-based agent, …).
NOT_LEARNED = "– (not learned)"
#: The teacher column of an agent that learned from the reward alone.
REWARD_ALONE = "none (reward alone)"


def teacher_label(hp: Hyperparams) -> str:
    """How an agent trained with ``hp`` learned (SPEC §8: every table says it): from the
    reward alone, or with guided exploration and/or imitation of the rule-based agent."""
    pairs = (("guided exploration", hp.explore_guide), ("imitation", hp.imitation_weight))
    return " + ".join(name for name, value in pairs if float(value) > 0.0) or REWARD_ALONE


#: Names of trained agents in results tables (:func:`agent_name`).
LEARNED_AGENTS = ("drqn", "dqn", "ppo", "ppo-ff", "pqn", "pqn-ff")


def agent_name(config: TrainConfig) -> str:
    """The name of the agent ``config`` trains in results tables: the network kind of the
    paper's learner, or ``"ppo"``/``"pqn"``, ``-ff`` when feed-forward (kind ``"dqn"``)."""
    if config.algorithm in ON_POLICY:
        name = config.algorithm
        return name if config.network.kind == "drqn" else f"{name}-ff"
    return config.network.kind


def has_teacher(label: str | None) -> bool:
    """Whether a :func:`teacher_label` names a teacher (False for the reward alone,
    a policy that did not learn, or a result without the label)."""
    return label not in (None, "–", REWARD_ALONE, NOT_LEARNED)


def teachers_of(results: Any) -> str:
    """The teacher column of a row pooling several runs' results (their distinct
    ``teacher`` labels; – for a result that names none)."""
    return " / ".join(sorted({r.get("teacher") or "–" for r in results}))


def step_share(config: TrainConfig, env_steps: jax.Array) -> jax.Array | None:
    """() float32 share of ``num_env_steps`` taken, or None without a step budget."""
    if not config.num_env_steps:
        return None
    return jnp.minimum(env_steps * (1.0 / config.num_env_steps), 1.0)


def annealed(
    hp: Hyperparams, recorded: jax.Array, num_episodes: int, steps: jax.Array | None = None
) -> Hyperparams:
    """``hp`` with this point of the run's learning rate: linear from ``learning_rate``
    to ``learning_rate · learning_rate_end`` over the recorded episodes or the ``steps``
    share of a step budget (:func:`step_share`), the further; constant at end 1."""
    frac = jnp.minimum(recorded * (1.0 / num_episodes), 1.0)
    if steps is not None:
        frac = jnp.maximum(frac, steps)
    scale = 1.0 + (hp.learning_rate_end - 1.0) * frac
    return hp.replace(learning_rate=hp.learning_rate * scale)


def _field(default: Any, doc: str, choices: tuple[str, ...] | None = None) -> Any:
    """A :class:`TrainConfig` field with its ``doc`` (and ``choices``) for the config schema."""
    meta = {"doc": doc} if choices is None else {"doc": doc, "choices": choices}
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass(frozen=True, eq=False)
class TrainConfig:
    """Shape-setting training settings (hashable; a change recompiles); the defaults
    are the paper's protocol (SPEC §7).

    ``hyperparams`` is only the default a run starts from: ``init`` copies it (or the
    ``hparams`` it is given) into the state, which everything traced reads. Equality
    and hashing compare it; the compiled programs depend on :meth:`program_key` alone.
    """

    env_id: str = "UrbanPedestrians-v0"
    env_overrides: tuple[tuple[str, Any], ...] = ()
    network: NetworkConfig = dataclasses.field(default_factory=NetworkConfig)
    algorithm: str = _field(
        "dqn",
        "the learner: 'dqn' (the paper: Double-DQN on an episode replay), 'ppo' "
        "(recurrent PPO, PureJaxRL's ppo_rnn; the replay and ε fields are unused) or "
        "'pqn' (recurrent PQN, purejaxql's pqn_rnn: ε-greedy rollouts, Q(λ) targets, "
        "no replay and no target network)",
        ALGORITHMS,
    )
    num_envs: int = 1
    num_episodes: int = 200
    num_env_steps: int = _field(
        0,
        "if > 0, the run also ends after this many env steps (all envs together), "
        "and ε and the learning rate follow the larger share of either budget; "
        "0 = the paper: num_episodes alone",
    )
    replay_episodes: int = 50
    batch_size: int = 32
    window: int = 8
    n_step: int = _field(1, "rewards summed per TD target, <= window (1 = the paper)")
    burn_in: int = _field(
        0,
        "steps before each replayed window that only warm the LSTM, without "
        "loss or gradient (R2D2's burn-in; 0 = the paper: the LSTM starts from zeros)",
    )
    stored_state: int = _field(
        0,
        "1: the replay keeps the acting LSTM's state with every observation and "
        "each replayed window starts from it (R2D2's stored state; drqn only; 0 = the "
        "paper: from zeros)",
    )
    updates_per_step: int = 1
    chunk_iterations: int = _field(
        1000, "iterations per host chunk: env steps (dqn) or updates (ppo)"
    )
    snapshots: int = _field(
        0,
        "parameter snapshots kept during training, the agent then chosen among them "
        "and the final parameters on validation episodes (0 = the paper: the final ones)",
    )
    validation_episodes: int = _field(100, "greedy episodes per candidate when snapshots > 0")
    rollout_steps: int = _field(128, "ppo, pqn: steps per env in each update's rollout")
    update_epochs: int = _field(4, "ppo, pqn: passes over each rollout")
    num_minibatches: int = _field(
        4, "ppo, pqn: minibatches per pass, of whole env sequences; divides num_envs"
    )
    optimizer: str = _field(
        "adam",
        "'adam' (the paper's) or 'radam' (rectified Adam, purejaxql's PQN); "
        "its settings are adam_b1, adam_b2, adam_eps",
        OPTIMIZERS,
    )
    hyperparams: Hyperparams = dataclasses.field(default_factory=Hyperparams)

    def __post_init__(self) -> None:
        counts = ("num_envs", "num_episodes", "replay_episodes", "batch_size", "window")
        counts += ("n_step", "updates_per_step", "chunk_iterations", "validation_episodes")
        check_counts(self, (*counts, "rollout_steps", "update_epochs", "num_minibatches"))
        check_counts(self, ("burn_in", "num_env_steps"), low=0)
        if self.num_env_steps and self.snapshots:
            raise ValueError(
                f"TrainConfig.snapshots = {self.snapshots}: snapshots are taken at shares of "
                "num_episodes, which a run with num_env_steps > 0 may not reach; use 0"
            )
        for name, choices in (("optimizer", OPTIMIZERS), ("algorithm", ALGORITHMS)):
            if getattr(self, name) not in choices:
                value = getattr(self, name)
                raise ValueError(f"TrainConfig.{name} = {value!r}: must be one of {choices}")
        if self.stored_state not in (0, 1) or isinstance(self.stored_state, bool):
            raise ValueError(f"TrainConfig.stored_state = {self.stored_state!r}: must be 0 or 1")
        if not isinstance(self.snapshots, int) or isinstance(self.snapshots, bool):
            raise ValueError(f"TrainConfig.snapshots = {self.snapshots!r}: must be an integer")
        most = self.num_episodes // self.num_envs - 1
        if not 0 <= self.snapshots <= most:
            raise ValueError(
                f"TrainConfig.snapshots = {self.snapshots}: must be in [0, {most}] "
                f"(num_episodes // num_envs - 1): snapshots are taken at least num_envs "
                "episodes apart, the most that end in one iteration"
            )
        scale = float(self.hyperparams.reward_scale)
        if self.algorithm != "pqn" and scale != 1.0:
            raise ValueError(
                f"Hyperparams.reward_scale = {scale:g}: only algorithm 'pqn' scales its "
                f"rewards (algorithm {self.algorithm!r}); use 1"
            )
        if self.algorithm in ON_POLICY:
            self._check_on_policy()
        else:
            self._check_dqn()

    def _check_dqn(self) -> None:
        """The replay's rules (algorithm ``"dqn"``)."""
        if self.stored_state and self.network.kind != "drqn":
            raise ValueError(
                f"TrainConfig.stored_state = 1: network kind {self.network.kind!r} has no "
                "recurrent state to store; use kind 'drqn' or stored_state = 0"
            )
        if self.n_step > self.window:
            raise ValueError(
                f"TrainConfig.n_step = {self.n_step}: must be <= window ({self.window}); "
                "an n-step target sums rewards inside one window"
            )
        if self.replay_episodes < 2 * self.num_envs:
            raise ValueError(
                f"TrainConfig.replay_episodes = {self.replay_episodes}: must be >= 2 × num_envs "
                f"({2 * self.num_envs}); each environment writes its own replay slots"
            )
        most_complete = self.num_envs * (self.replay_episodes // self.num_envs - 1)
        starts = int(self.hyperparams.learning_starts)
        if starts > most_complete:
            raise ValueError(
                f"Hyperparams.learning_starts = {starts}: must be <= {most_complete}, the most "
                f"complete episodes a replay of {self.replay_episodes} holds while "
                f"{self.num_envs} environments write (learning would never start)"
            )

    def _check_on_policy(self) -> None:
        """The rules of the learners without a replay (``ON_POLICY``): whole env
        sequences per minibatch, none of the replay learner's options."""
        name = self.algorithm
        if self.num_envs % self.num_minibatches:
            raise ValueError(
                f"TrainConfig.num_minibatches = {self.num_minibatches}: must divide num_envs "
                f"({self.num_envs}); a minibatch holds whole env sequences"
            )
        for field in ("stored_state", "burn_in", "snapshots"):
            if getattr(self, field):
                raise ValueError(
                    f"TrainConfig.{field} = {getattr(self, field)}: algorithm {name!r} has no "
                    "replay and no snapshot selection; use 0"
                )
        for field in ("explore_guide", "imitation_weight", "value_rescale"):
            if float(getattr(self.hyperparams, field)) > 0.0:
                raise ValueError(
                    f"Hyperparams.{field} = {float(getattr(self.hyperparams, field))}: "
                    f"algorithm {name!r} learns from the reward alone, without it; use 0"
                )

    def program_key(self) -> tuple:
        """Every field but ``hyperparams``: what a compiled program of ``make_train``'s
        functions depends on when it takes the hyperparameters as arguments (as the
        runners' programs do); configs differing in hyperparameter values share it."""
        return tuple(
            getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "hyperparams"
        )

    def __hash__(self) -> int:  # Hyperparams holds arrays: hash the static part only
        return hash(self.program_key())

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TrainConfig):
            return NotImplemented
        # on the host, in numpy: a store lookup may compare configs inside a trace,
        # where a jnp comparison would be staged out and have no truth value
        mine, theirs = jax.tree.leaves(self.hyperparams), jax.tree.leaves(other.hyperparams)
        return self.program_key() == other.program_key() and all(
            np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(mine, theirs, strict=True)
        )
