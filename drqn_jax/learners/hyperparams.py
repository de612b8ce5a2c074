"""Training settings (paper Table II; SPEC §7): the traced :class:`Hyperparams` (a sweep
``vmap``s over them), the shape-setting :class:`TrainConfig`, and an agent's name in tables."""

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.env.params import KMH
from drqn_jax.learners.optim import OPTIMIZERS
from drqn_jax.networks import NetworkConfig
from drqn_jax.pytree import check_counts, check_sums_to_one, param, pytree_dataclass, validate

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
    """Traced training hyperparameters (paper Table II; SPEC §7); "0 = the paper"
    marks an extension off by default."""

    learning_rate: float = param(1e-3, low=0.0, low_open=True)
    learning_rate_end: float = param(1.0, low=0.0, high=1.0, doc="end fraction (linear)")
    adam_b1: float = param(0.9, low=0.0, high=1.0, high_open=True)
    adam_b2: float = param(0.999, low=0.0, high=1.0, high_open=True)
    adam_eps: float = param(1e-8, low=0.0, low_open=True)
    gamma: float = param(0.9, low=0.0, high=1.0)
    epsilon_start: float = param(1.0, low=0.0, high=1.0)
    epsilon_end: float = param(0.1, low=0.0, high=1.0)
    # share of the episodes over which ε falls, then stays (SB3's exploration_fraction)
    epsilon_fraction: float = param(1.0, low=0.0, high=1.0, low_open=True)
    explore_bias_fraction: float = param(0.1, low=0.0, high=1.0)
    explore_accelerate: float = param(0.4, low=0.0, high=1.0)
    explore_slow_down: float = param(0.1, low=0.0, high=1.0)
    explore_brake: float = param(0.1, low=0.0, high=1.0)
    explore_steer: float = param(0.4, low=0.0, high=1.0)
    # the rule-based agent's share of exploratory actions
    explore_guide: float = param(0.0, low=0.0, high=1.0)
    target_period: int = param(10_000, low=1, doc="gradient steps between target copies")
    learning_starts: int = param(4, low=1, doc="complete episodes in replay before learning")
    clip: int = param("huber", choices=CLIP_MODES)
    # 'inside' the episode (SPEC §7) or 'anywhere', padded past its end
    window_start: int = param("inside", choices=WINDOW_STARTS)
    # DQfD's large-margin term toward the rule-based agent's (SPEC §6) action, in the
    # replayed states of imitation_states, its margin, and the imitated agent's settings
    imitation_weight: float = param(0.0, low=0.0)
    imitation_margin: float = param(1.0, low=0.0, low_open=True)
    imitation_states: int = param("brake", choices=IMITATION_STATES)
    imitation_lookahead: float = param(7.0, low=0.0, doc="m (SPEC §6: 7)")
    imitation_corridor_margin: float = param(0.5, low=0.0, doc="m (SPEC §6: 0.5)")
    imitation_v_max: float = param(15.0 * KMH, low=0.0, low_open=True, doc="m/s (15 km/h)")
    imitation_horizon: float = param(0.0, low=0.0, doc="s (RuleBasedParams.horizon)")
    # 1: learn h(Q) with targets h(r + γ h⁻¹(Q')), R2D2's rescaling (Kapturowski et al. 2019)
    value_rescale: int = param(0, low=0, high=1)
    # with snapshots > 0: the best mean 'return', or the 'safe' candidate (most
    # collision-free at select_speed_floor m/s or faster) on the validation episodes
    select_by: int = param("return", choices=SELECT_BY)
    select_speed_floor: float = param(0.0, low=0.0)
    gae_lambda: float = param(0.95, low=0.0, high=1.0, doc="ppo: λ of GAE")
    q_lambda: float = param(0.95, low=0.0, high=1.0, doc="pqn: λ of Q(λ) (purejaxql: 0.95)")
    # pqn: the Q(λ) targets' reward factor (purejaxql's REW_SCALE); 1 for the others
    reward_scale: float = param(1.0, low=0.0, low_open=True)
    clip_eps: float = param(0.2, low=0.0, low_open=True, doc="ppo: ratio and value clip")
    ent_coef: float = param(0.01, low=0.0, doc="ppo: weight of the entropy bonus")
    vf_coef: float = param(0.5, low=0.0, doc="ppo: weight of the value loss")
    # ppo, pqn: gradients scaled down to this global norm (PureJaxRL: 0.5)
    max_grad_norm: float = param(0.5, low=0.0, low_open=True)

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


def agent_name(config: "TrainConfig") -> str:
    """The name of the agent ``config`` trains in results tables: the network kind of the
    paper's learner, or ``"ppo"``/``"pqn"``, ``-ff`` when feed-forward (kind ``"dqn"``)."""
    if config.algorithm in ON_POLICY:
        return config.algorithm + ("" if config.network.kind == "drqn" else "-ff")
    return config.network.kind


def has_teacher(label: str | None) -> bool:
    """Whether a :func:`teacher_label` names a teacher (False for the reward alone,
    a policy that did not learn, or a result without the label)."""
    return label not in (None, "–", REWARD_ALONE, NOT_LEARNED)


def teachers_of(results: Any) -> str:
    """The teacher column of a row pooling several runs' results (their distinct
    ``teacher`` labels; – for a result that names none)."""
    return " / ".join(sorted({r.get("teacher") or "–" for r in results}))


def step_share(config: "TrainConfig", env_steps: jax.Array) -> jax.Array | None:
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


@dataclasses.dataclass(frozen=True, eq=False)
class TrainConfig:
    """Shape-setting training settings (hashable); defaults are the paper's protocol (SPEC §7),
    "0 = the paper" an extension off. ``hyperparams`` is the default ``init`` copies into the
    state, which everything traced reads; equality and hashing compare it, compiled programs
    depend on :meth:`program_key` alone."""

    env_id: str = "UrbanPedestrians-v0"
    env_overrides: tuple[tuple[str, Any], ...] = ()
    network: NetworkConfig = dataclasses.field(default_factory=NetworkConfig)
    # 'dqn' (the paper: Double DQN on an episode replay), 'ppo' (PureJaxRL's ppo_rnn)
    # or 'pqn' (purejaxql's pqn_rnn); the last two have no replay
    algorithm: str = dataclasses.field(default="dqn", metadata={"choices": ALGORITHMS})
    num_envs: int = 1
    num_episodes: int = 200
    # > 0: the run also ends after this many env steps (all envs), and ε and the
    # learning rate follow the larger share of either budget
    num_env_steps: int = 0
    replay_episodes: int = 50
    batch_size: int = 32
    window: int = 8
    n_step: int = 1  # rewards summed per TD target, <= window
    burn_in: int = 0  # steps before each window that only warm the LSTM (R2D2)
    stored_state: int = 0  # 1: windows start from the stored acting state (R2D2; drqn)
    updates_per_step: int = 1
    chunk_iterations: int = 1000  # per host chunk: env steps (dqn) or updates
    # snapshots kept; the agent is chosen among them and the final parameters
    snapshots: int = 0
    validation_episodes: int = 100  # greedy episodes per candidate
    rollout_steps: int = 128  # ppo, pqn: steps per env in each rollout
    update_epochs: int = 4  # ppo, pqn: passes over each rollout
    num_minibatches: int = 4  # ppo, pqn: of whole env sequences; divides num_envs
    # pqn: steps of the previous rollout trained again before each rollout, the unroll
    # starting from the state they were acted from (purejaxql's MEMORY_WINDOW)
    memory_window: int = 0
    # 'adam' (the paper's) or 'radam' (purejaxql's PQN), at adam_b1, adam_b2, adam_eps
    optimizer: str = dataclasses.field(default="adam", metadata={"choices": OPTIMIZERS})
    hyperparams: Hyperparams = dataclasses.field(default_factory=Hyperparams)

    def __post_init__(self) -> None:
        counts = ("num_envs", "num_episodes", "replay_episodes", "batch_size", "window")
        counts += ("n_step", "updates_per_step", "chunk_iterations", "validation_episodes")
        check_counts(self, (*counts, "rollout_steps", "update_epochs", "num_minibatches"))
        check_counts(self, ("burn_in", "num_env_steps", "memory_window"), low=0)
        if self.memory_window and self.algorithm != "pqn":
            raise ValueError(
                f"TrainConfig.memory_window = {self.memory_window}: only algorithm 'pqn' has "
                f"a memory window (algorithm {self.algorithm!r}); use 0"
            )
        if self.memory_window > self.rollout_steps:
            raise ValueError(
                f"TrainConfig.memory_window = {self.memory_window}: must be in [0, "
                f"{self.rollout_steps}] (rollout_steps): the window is the previous rollout's end"
            )
        if self.num_env_steps and self.snapshots:
            raise ValueError(
                f"TrainConfig.snapshots = {self.snapshots}: snapshots are taken at shares of "
                "num_episodes, which a run with num_env_steps > 0 may not reach; use 0"
            )
        for name, choices in (("optimizer", OPTIMIZERS), ("algorithm", ALGORITHMS)):
            if (value := getattr(self, name)) not in choices:
                raise ValueError(f"TrainConfig.{name} = {value!r}: must be one of {choices}")
        if self.stored_state not in (0, 1) or isinstance(self.stored_state, bool):
            raise ValueError(f"TrainConfig.stored_state = {self.stored_state!r}: must be 0 or 1")
        most = self.num_episodes // self.num_envs - 1  # snapshots at least num_envs apart
        if type(self.snapshots) is not int or not 0 <= self.snapshots <= most:
            raise ValueError(
                f"TrainConfig.snapshots = {self.snapshots!r}: must be in [0, {most}], an "
                "integer (num_episodes // num_envs - 1)"
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
                f"TrainConfig.n_step = {self.n_step}: must be <= window ({self.window})"
            )
        if self.replay_episodes < 2 * self.num_envs:
            raise ValueError(
                f"TrainConfig.replay_episodes = {self.replay_episodes}: must be >= 2 × "
                f"num_envs ({2 * self.num_envs}); each env writes its own replay slots"
            )
        most_complete = self.num_envs * (self.replay_episodes // self.num_envs - 1)
        starts = int(self.hyperparams.learning_starts)
        if starts > most_complete:
            raise ValueError(
                f"Hyperparams.learning_starts = {starts}: must be <= {most_complete}, the most "
                "complete episodes the replay holds while its envs write"
            )

    def _check_on_policy(self) -> None:
        """The rules of the learners without a replay (``ON_POLICY``)."""
        name = self.algorithm
        if self.num_envs % self.num_minibatches:
            raise ValueError(
                f"TrainConfig.num_minibatches = {self.num_minibatches}: must divide num_envs "
                f"({self.num_envs}); a minibatch holds whole env sequences"
            )
        for field in ("stored_state", "burn_in", "snapshots"):
            if value := getattr(self, field):
                raise ValueError(
                    f"TrainConfig.{field} = {value}: algorithm {name!r} has no "
                    "replay and no snapshot selection; use 0"
                )
        for field in ("explore_guide", "imitation_weight", "value_rescale"):
            if (value := float(getattr(self.hyperparams, field))) > 0.0:
                raise ValueError(
                    f"Hyperparams.{field} = {value}: "
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
