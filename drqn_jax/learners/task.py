"""What a learner needs of an env beyond the gymnax contract (SPEC §7), a :class:`Task`:
:func:`urban_task` for the paper's env, :func:`gymnax_task` for any ``"gymnax:<name>"``
(gymnax >= 1.0, which tells truncation from termination)."""

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from drqn_jax.agents.base import drqn_agent
from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_action, rule_based_labels
from drqn_jax.env.grid import GridInputs, rasterize
from drqn_jax.env.params import EnvParams, StaticEnvParams
from drqn_jax.env.state import Observation
from drqn_jax.evaluation import run_episodes
from drqn_jax.networks import NetworkConfig
from drqn_jax.registry import make

#: Env ids with this prefix name a gymnax environment (``gymnax.make``).
GYMNAX_PREFIX = "gymnax:"
#: The rule-based agent that guides exploration (SPEC §6, its default thresholds).
RULE_BASED_GUIDE = RuleBasedParams()


class Step(NamedTuple):
    """One vectorised env step as the learner sees it (leaves (N, …)); ``final`` is
    the pre-reset record, ``info`` what ``episode_metrics`` reads."""

    obs: Any
    state: Any
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    final: Any
    info: dict[str, jax.Array]


class Teacher(NamedTuple):
    """The rule-based agent as a teacher (not the paper's): ``act`` () int32 in one
    env (guided exploration), ``labels`` (…) int32 on replayed records (imitation)."""

    act: Callable[[Any, Any], jax.Array]
    labels: Callable[[Any, Any, Any], jax.Array]


class Task(NamedTuple):
    """A gymnax env with what a learner needs: ``max_steps`` (a replay slot), ``decision_steps``
    (1 for gymnax), ``record`` (zeros of one), ``step`` -> :class:`Step` (auto-reset),
    ``observe(records, last_action, params)`` on (T, B, …), ``network`` (completes the config),
    ``explore_bias(hp)`` (A,), ``validate`` -> {metric: ()} for snapshot selection."""

    env: Any
    env_params: Any
    num_actions: int
    max_steps: int
    record: Any
    reset: Callable[[jax.Array, Any], tuple[Any, Any]]
    step: Callable[[jax.Array, Any, jax.Array, Any], Step]
    to_record: Callable[[Any, Any], Any]
    observe: Callable[[Any, jax.Array, Any], Any]
    network: Callable[[NetworkConfig], NetworkConfig]
    metrics: tuple[tuple[str, Any], ...]
    episode_metrics: Callable[[Step, Any], dict[str, jax.Array]]
    explore_bias: Callable[[Any], jax.Array]
    validate: Callable[..., dict[str, jax.Array]]
    validation_metrics: tuple[str, ...]
    teacher: Teacher | None = None
    decision_steps: int = 1


def make_task(env_id: str, overrides: tuple[tuple[str, Any], ...] = ()) -> Task:
    """The task of ``env_id``: a registered ``drqn_jax`` id, or ``"gymnax:<name>"``."""
    if env_id.startswith(GYMNAX_PREFIX):
        return gymnax_task(env_id.removeprefix(GYMNAX_PREFIX), **dict(overrides))
    return urban_task(env_id, **dict(overrides))


def observations(
    records: GridInputs, last_action: jax.Array, params: EnvParams, static: StaticEnvParams
) -> Observation:
    """Rasterise records of any leading shape into observations (as the env does)."""
    lead = records.s.shape
    flat = jax.tree.map(lambda x: x.reshape((-1, *x.shape[len(lead) :])), records)
    grid = jax.vmap(rasterize, (0, None, None))(flat, params, static)
    return Observation(
        grid=grid.reshape((*lead, *grid.shape[1:])),
        speed=(records.v * (1.0 / params.v_ref)).astype(jnp.float32),
        last_action=last_action.astype(jnp.int32),
    )


def urban_task(env_id: str = "UrbanPedestrians-v0", **overrides: Any) -> Task:
    """The paper's env (paper §IV; SPEC §1-5), its rule-based agent as teacher."""
    env, params = make(env_id, **overrides)
    static = env.static

    def step(key, state, action, params) -> Step:
        obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
        final = info["final_state"]
        return Step(obs, state, reward, terminated, truncated, _grid_record(final), info)

    def episode_metrics(step: Step, params: EnvParams) -> dict:
        info = step.info
        duration = info["time"].astype(jnp.float32) * params.dt  # ticks: k per decision
        return {
            "collision": info["collision"],
            "goal": info["goal"],
            "distance": info["distance"],
            "mean_speed": info["distance"] / duration,
        }

    def explore_bias(hp: Any) -> jax.Array:
        return jnp.stack(
            [hp.explore_accelerate, hp.explore_slow_down, hp.explore_brake, hp.explore_steer]
        )

    def labels(records: GridInputs, params: EnvParams, hp: Any) -> jax.Array:
        expert = RULE_BASED_GUIDE.replace(
            lookahead=hp.imitation_lookahead,
            corridor_margin=hp.imitation_corridor_margin,
            v_max=hp.imitation_v_max,
            horizon=hp.imitation_horizon,
        )
        return rule_based_labels(records, params, expert, static)

    def validate(network, agent_params, keys, env_params) -> dict[str, jax.Array]:
        """Mean greedy return, collision-free share and mean speed (m/s) over ``keys``'
        episodes."""
        episodes = run_episodes(drqn_agent(network, agent_params), keys, env, env_params)
        return {
            "return": jnp.mean(episodes.episode_return),
            "collision_free": jnp.mean(1.0 - episodes.collision.astype(jnp.float32)),
            "speed": jnp.mean(episodes.mean_speed),
        }

    return Task(
        env=env,
        env_params=params,
        num_actions=env.num_actions,
        max_steps=-(-static.max_steps // static.decision_steps),  # decisions
        decision_steps=static.decision_steps,
        record=GridInputs.empty(static.num_pedestrians),
        reset=env.reset,
        step=step,
        to_record=lambda obs, state: _grid_record(state),
        observe=lambda records, last, params: observations(records, last, params, static),
        network=lambda net: dataclasses.replace(net, grid_shape=static.grid_shape),
        metrics=(
            ("collision", jnp.bool_),
            ("goal", jnp.bool_),
            ("distance", jnp.float32),
            ("mean_speed", jnp.float32),
        ),
        episode_metrics=episode_metrics,
        explore_bias=explore_bias,
        teacher=Teacher(
            act=lambda state, params: rule_based_action(state, params, RULE_BASED_GUIDE, static),
            labels=labels,
        ),
        validate=validate,
        validation_metrics=("return", "collision_free", "speed"),
    )


def _grid_record(state: Any) -> GridInputs:
    return GridInputs.of(state.ego, state.pedestrians)


def gymnax_task(name: str, max_steps: int | None = None, **overrides: Any) -> Task:
    """``gymnax.make(name)``, observations flattened for the MLP torso; ``max_steps``
    (default ``max_steps_in_episode``) is the replay's slot length, ``overrides``
    fields of its ``EnvParams``."""
    try:
        import gymnax
    except ImportError as err:  # pragma: no cover - depends on the install
        raise ImportError(
            f"env id {GYMNAX_PREFIX}{name}: gymnax is not installed; see the README "
            "(pip install --no-deps gymnax, with the test extra)"
        ) from err
    env, params = gymnax.make(name)
    unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(params)})
    if unknown:
        raise ValueError(f"gymnax_task({name!r}): unknown EnvParams field(s) {unknown}")
    params = params.replace(**overrides)
    shape = env.observation_space(params).shape
    longest = int(params.max_steps_in_episode) if max_steps is None else max_steps
    n_actions = int(env.num_actions)

    size = math.prod(shape)

    def flat(obs: Any) -> jax.Array:  # the MLP torso reads a flat float vector
        return jnp.asarray(obs, jnp.float32).reshape(size)

    def reset(key, params) -> tuple[jax.Array, Any]:
        obs, state = env.reset(key, params)
        return flat(obs), state

    def step(key, state, action, params) -> Step:
        obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
        reward = jnp.asarray(reward, jnp.float32)
        terminated, truncated = jnp.asarray(terminated, bool), jnp.asarray(truncated, bool)
        return Step(
            flat(obs), state, reward, terminated, truncated, flat(info["final_observation"]), {}
        )

    task = Task(
        env=env,
        env_params=params,
        num_actions=n_actions,
        max_steps=longest,
        record=jnp.zeros((size,), jnp.float32),
        reset=reset,
        step=step,
        to_record=lambda obs, state: obs,
        observe=lambda records, last, params: records,
        network=lambda net: dataclasses.replace(
            net, torso="mlp", obs_size=size, num_actions=n_actions
        ),
        metrics=(),
        episode_metrics=lambda step, params: {},
        explore_bias=lambda hp: jnp.full((n_actions,), 1.0 / n_actions),
        validate=lambda network, params, keys, env_params: {
            "return": jnp.mean(greedy_returns(task, network, params, keys, env_params))
        },
        validation_metrics=("return",),
    )
    return task


def greedy_returns(
    task: Task, network: Any, params: Any, keys: jax.Array, env_params: Any = None
) -> jax.Array:
    """(E,) float32 greedy (``argmax Q``) returns, one episode per key of ``keys`` (E,):
    ``max_steps`` steps each, branch-free, those after the episode's end not counted."""
    env_params = task.env_params if env_params is None else env_params

    def body(loop, k):
        obs, state, carry, ret, done = loop
        q, carry = network.step(params, obs, carry)
        out = task.step(k, state, jnp.argmax(q).astype(jnp.int32), env_params)
        ret = ret + jnp.where(~done, out.reward, 0.0)
        done = done | out.terminated | out.truncated
        return (out.obs, out.state, carry, ret, done), None

    def play(key: jax.Array) -> jax.Array:
        k_reset, k_run = jax.random.split(key)
        obs, state = task.reset(k_reset, env_params)
        init = (
            obs,
            state,
            network.initial_carry(()),
            jnp.zeros((), jnp.float32),
            jnp.asarray(False),
        )
        steps = jax.random.split(k_run, task.max_steps)
        return jax.lax.scan(body, init, steps)[0][3]

    return jax.vmap(play)(keys)
