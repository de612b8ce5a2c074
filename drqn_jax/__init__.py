"""drqn_jax: a JAX urban-pedestrian simulator and DRQN trainer (after Deshpande et al.).

Importing it caps XLA:CPU code generation at AVX (:mod:`drqn_jax.determinism`)."""

from drqn_jax.determinism import configure_xla_flags

configure_xla_flags()

from drqn_jax.agents import (  # noqa: E402
    Agent,
    RuleBasedParams,
    constant_agent,
    drqn_agent,
    random_agent,
    rule_based_agent,
)
from drqn_jax.env.params import EnvParams, StaticEnvParams  # noqa: E402
from drqn_jax.env.state import ACTIONS, EnvState, Observation  # noqa: E402
from drqn_jax.env.urban import UrbanPedestrians  # noqa: E402
from drqn_jax.evaluation import EpisodeMetrics, evaluate, run_episodes, summarize  # noqa: E402
from drqn_jax.interop.gymnasium_env import (  # noqa: E402
    UrbanPedestriansGymEnv,
    register_gymnasium_envs,
)
from drqn_jax.interop.gymnasium_vector import UrbanPedestriansVectorEnv  # noqa: E402
from drqn_jax.learners import Hyperparams, TrainConfig, make_train  # noqa: E402
from drqn_jax.registry import make, registered_envs  # noqa: E402

register_gymnasium_envs()  # gymnasium.make("drqn_jax/UrbanPedestrians-v0"), make_vec(...)

__version__ = "0.1.0"

__all__ = [
    "ACTIONS",
    "Agent",
    "EnvParams",
    "EnvState",
    "EpisodeMetrics",
    "Hyperparams",
    "Observation",
    "RuleBasedParams",
    "StaticEnvParams",
    "TrainConfig",
    "UrbanPedestrians",
    "UrbanPedestriansGymEnv",
    "UrbanPedestriansVectorEnv",
    "constant_agent",
    "drqn_agent",
    "evaluate",
    "make",
    "make_train",
    "random_agent",
    "register_gymnasium_envs",
    "registered_envs",
    "rule_based_agent",
    "run_episodes",
    "summarize",
]
