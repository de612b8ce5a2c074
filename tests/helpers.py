"""Shared test helpers: jitted rollouts reused across test modules."""

from __future__ import annotations

import os
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.config import load_config
from drqn_jax.env.road_map import WALKWAY, semantic_class
from drqn_jax.env.state import SIDEWALK
from drqn_jax.experiments.frontier import with_margin
from drqn_jax.experiments.rows import baseline_row
from drqn_jax.learners import Hyperparams, TrainConfig, make_train

#: The smoke config as test_sweep's sweep sets it. test_study and test_memory
#: train with the same settings so that the suite compiles those programs once
#: (JAX's persistent compilation cache, tests/conftest.py, serves them to
#: whichever file runs later): about half a minute of compiling each on 2 cores.
SMOKE_SWEEP_SET = ("train.num_episodes=4", "train.snapshots=1", "train.validation_episodes=2")

#: smoke.toml's iterations per chunk: the runner's ``run`` program (test_cli's smoke run).
SMOKE_CHUNK = load_config("smoke")["train"]["chunk_iterations"]

#: test_sweep's sweep file: 2 seeds × 2 learning rates of that config (one program).
SMOKE_SWEEP = """
base = "smoke"
[set]
{}
[axes]
"run.seed" = {{ start = 0, stop = 2 }}
"train.learning_rate" = [1e-3, 3e-4]
""".format("\n".join('"{}" = {}'.format(*s.split("=")) for s in SMOKE_SWEEP_SET))


#: XLA:CPU compiler options without LLVM's optimisation: a program compiles in half to
#: two thirds of the time and runs slower. Its floating point rounds differently from
#: the default level's, so only a test that compares a
#: program's outputs with each other, or with a reference within a tolerance, may
#: compile with it: never one that checks the bits a user's program gives.
FAST_COMPILE = {"xla_backend_optimization_level": 0}


def fast_jit(fun, **options):
    """``jax.jit(fun, **options)`` compiled with :data:`FAST_COMPILE` (see there)."""
    return jax.jit(fun, compiler_options=FAST_COMPILE, **options)


def fast_compile_env() -> dict[str, str]:
    """This process's environment with ``XLA_FLAGS`` asking for :data:`FAST_COMPILE`,
    for a subprocess whose outputs the test compares with no other program's bits."""
    flags = " ".join(f"--{name}={value}" for name, value in FAST_COMPILE.items())
    return {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} {flags}".strip()}


def tree_equal(a, b) -> bool:
    """Bitwise equality of two pytrees (structure, shapes, dtypes, values incl. NaN/inf)."""
    la, ta = jax.tree.flatten(a)
    lb, tb = jax.tree.flatten(b)
    if ta != tb:
        return False
    return all(
        np.asarray(x).dtype == np.asarray(y).dtype
        and np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
        for x, y in zip(la, lb, strict=True)
    )


def assert_tree_equal(a, b) -> None:
    la = jax.tree_util.tree_leaves_with_path(a)
    lb = jax.tree.leaves(b)
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for (path, x), y in zip(la, lb, strict=True):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype, jax.tree_util.keystr(path)
        assert np.array_equal(x, y, equal_nan=True), (
            f"{jax.tree_util.keystr(path)} differs: max |diff| "
            f"{np.max(np.abs(x.astype(np.float64) - y.astype(np.float64)))}"
        )


def flat_random(sample, key: jax.Array, shape: tuple[int, ...], *args) -> jax.Array:
    """``sample(key, shape, *args)`` (``jax.random.uniform``, ``randint``, ...) drawn
    as a flat vector and reshaped: the same values (threefry's counter is the
    row-major index), but a compile that does not grow with the rank. On XLA:CPU
    a (3, 2, 45, 30, 4) ``uniform`` takes about 5 s to compile, its flat draw 0.4 s."""
    return sample(key, (int(np.prod(shape)),), *args).reshape(shape)


def take(tree, i):
    """Element ``i`` of every leaf's leading axis."""
    return jax.tree.map(lambda x: x[i], tree)


def bit_hash(x: jax.Array, axes: tuple[int, ...]) -> jax.Array:
    """Exact, order-independent fingerprint of float32 values over ``axes``.

    Sums the bit patterns, weighted by position, in wrapping uint32 arithmetic,
    so (unlike a float sum) it does not depend on how XLA orders the reduction.
    """
    bits = jax.lax.bitcast_convert_type(x.astype(jnp.float32), jnp.uint32)
    shape = [x.shape[a] for a in axes]
    weight = (
        jnp.arange(int(np.prod(shape)), dtype=jnp.uint32) * jnp.uint32(2654435761) + jnp.uint32(1)
    ).reshape(shape)
    weight = jnp.expand_dims(weight, [i for i in range(x.ndim) if i not in axes])
    return jnp.sum(bits * weight, axis=axes, dtype=jnp.uint32)


def random_rollout(env, params, key, num_steps: int, keep_final: bool = False):
    """Single-env rollout with uniform random actions and auto-reset.

    Returns per-step (obs, reward, terminated, truncated, info-without-final-obs)
    with a leading time axis, and the final state. Vmappable over ``key``.
    """
    key_reset, key_run = jax.random.split(key)
    _obs, state = env.reset(key_reset, params)

    def body(state, k):
        k_act, k_step = jax.random.split(k)
        action = jax.random.randint(k_act, (), 0, env.num_actions)
        obs, state, r, term, trunc, info = env.step(k_step, state, action, params)
        if not keep_final:
            info = {k: v for k, v in info.items() if not k.startswith("final_")}
        return state, (obs, r, term, trunc, info)

    state, out = jax.lax.scan(body, state, jax.random.split(key_run, num_steps))
    return out, state


@partial(jax.jit, static_argnames=("env", "num_steps"))
def batched_rollout_summary(env, params, keys, num_steps: int):
    """Random rollouts of len(keys) envs; per-step compact fingerprints (no grids kept).

    Returns a dict of (B, T) arrays: exact hashes of the observation grid and of
    the final (pre-reset) observation grid, rewards, flags, speeds, TTC, and
    the final states.
    """

    def one(key):
        out, state = random_rollout(env, params, key, num_steps, keep_final=True)
        obs, r, term, trunc, info = out
        final_grid = info["final_observation"].grid
        return {
            "grid_hash": bit_hash(obs.grid, (1, 2, 3)),  # (T,)
            "final_grid_hash": bit_hash(final_grid, (1, 2, 3)),
            "speed": obs.speed,
            "last_action": obs.last_action,
            "reward": r,
            "terminated": term,
            "truncated": trunc,
            "ttc": info["ttc"],
            "distance": info["distance"],
        }, state

    return jax.vmap(one)(keys)


@partial(jax.jit, static_argnames=("env", "num_steps"))
def invariant_rollout(env, params, keys, num_steps: int):
    """Random rollouts checking SPEC invariants at every step, inside the jit.

    Returns a dict of (B, T) bool arrays (True = invariant holds) and the
    number of pedestrians seen.
    """
    static = env.static

    def one(key):
        key_reset, key_run = jax.random.split(key)
        _obs, state = env.reset(key_reset, params)

        def body(state, k):
            k_act, k_step = jax.random.split(k)
            action = jax.random.randint(k_act, (), 0, env.num_actions)
            obs, state, r, _term, _trunc, info = env.step(k_step, state, action, params)
            peds = state.pedestrians
            cls = semantic_class(peds.position, params, static)
            g = obs.grid
            finite = jnp.array(
                [jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(state) if x.dtype.kind == "f"]
            )
            checks = {
                "sidewalk_on_walkway": jnp.all((peds.behaviour != SIDEWALK) | (cls == WALKWAY)),
                "occupancy_binary": jnp.all((g[..., 0] == 0) | (g[..., 0] == 1)),
                "heading_range": jnp.all((g[..., 1] >= -1) & (g[..., 1] <= 1)),
                "speed_range": jnp.all(
                    (g[..., 2] >= 0) & (g[..., 2] <= params.ped_speed_max / 2.0 + 1e-6)
                ),
                "semantic_range": jnp.all(
                    jnp.isin(g[..., 3], jnp.array([0.0, 1 / 3, 2 / 3, 1.0], jnp.float32))
                ),
                "empty_cells_zero": jnp.all((g[..., 0] == 1) | jnp.all(g == 0, axis=-1)),
                "reward_range": (r >= -10.0) & (r <= 1.0),
                "ego_speed_nonneg": (state.ego.v >= 0) & (obs.speed >= 0),
                "state_finite": jnp.all(finite),
                "obs_finite": jnp.all(jnp.isfinite(g)) & jnp.isfinite(obs.speed) & jnp.isfinite(r),
                "ttc_not_nan": ~jnp.isnan(info["ttc"]),
                "occupied_cells_le_P": jnp.sum(g[..., 0]) <= peds.position.shape[0],
            }
            return state, (checks, peds.position.shape[0])

        _, (checks, count) = jax.lax.scan(body, state, jax.random.split(key_run, num_steps))
        return checks, count

    return jax.vmap(one)(keys)


#: smoke.toml's network.
SMALL_NET = load_config("smoke").network_config()


def train_alone(point: Any) -> tuple[Any, dict[str, jax.Array]]:
    """A sweep point trained alone: ``jit(train)`` on its key, hyperparameters and
    env params, the last two as arguments (as in a sweep, and as ``drqn-jax train``
    carries them in the state), so every point of a shape shares one program
    (compiled once per process, then loaded from the persistent cache)."""
    trainer = make_train(point.config.train_config())
    hp, env_params = trainer.config.hyperparams, trainer.task.env_params
    return jax.jit(trainer.train)(point.config.keys()[0], hp, env_params)


def tiny_train_config(max_steps: int = 30, **changes: Any) -> TrainConfig:
    """A training config that compiles and runs in seconds (tests only).

    2 envs, 6 episodes of at most ``max_steps`` steps, replay of 4, batch 4 × 4,
    the narrow ``SMALL_NET``, learning from the first complete episode, target
    copy every 7 steps; ``changes`` replace any ``TrainConfig`` field.
    """
    base = dict(
        env_overrides=(("max_steps", max_steps),),
        network=SMALL_NET,
        num_envs=2,
        num_episodes=6,
        replay_episodes=4,
        batch_size=4,
        window=4,
        chunk_iterations=SMOKE_CHUNK,
        hyperparams=Hyperparams(learning_starts=1, target_period=7),
    )
    return TrainConfig(**{**base, **changes})


def policy_result(free: float, speed: float = 9.0) -> dict[str, Any]:
    """One policy's evaluation result: ``free`` collision-free over 1000 episodes (its
    interval ±3 points) at ``speed`` km/h (tests of tables and verdicts)."""
    return {
        "agent": "drqn",
        "num_episodes": 1000,
        "collision_free_rate": free,
        "collision_free_ci": [free - 0.03, free + 0.03],
        "avg_speed_kmh": speed,
        "avg_distance_m": 100.0,
        "goal_rate": 0.5,
        "teacher": "none (reward alone)",
    }


#: A hand-made (concave) rule-based frontier of world "W": 100 % standing, 90 % at
#: 2 km/h, 50 % at 6, 0 % at 10.
HAND_FRONTIER = {
    "world": "W",
    "rule_based": {
        "points": [
            {"avg_speed_kmh": v, "collision_free_rate": r}
            for v, r in [(0.0, 1.0), (2.0, 0.9), (6.0, 0.5), (10.0, 0.0)]
        ]
    },
}


def judged_row(free: float, speed: float) -> dict[str, Any]:
    """:func:`policy_result`'s row (label "d") with its margin to :data:`HAND_FRONTIER`
    (a speed limit of 15 km/h)."""
    return with_margin(
        baseline_row("d", policy_result(free, speed), world="W"), HAND_FRONTIER, 15.0
    )
