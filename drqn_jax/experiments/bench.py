"""Quick throughput figures for ``drqn-jax bench`` (the full studies are in ``benchmarks/``).

* :func:`bench_env`: env steps/s of the config's environment, ``num_envs``
  in parallel, random actions, one jitted ``lax.scan`` of ``steps`` steps;
* :func:`bench_train`: training iterations/s, env steps/s and gradient
  updates/s of the config's trainer over ``iterations`` iterations of
  ``run`` after learning has started.

Each figure is the best of 3 timed calls after a warm-up call; compile time
(lower + compile) is reported separately.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax

from drqn_jax.config import Config
from drqn_jax.experiments.runner import init_program
from drqn_jax.learners import make_train

__all__ = ["bench_env", "bench_train"]


def _best_of(fn: Callable[[], Any], repeats: int = 3) -> float:
    jax.block_until_ready(fn())  # warm-up
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - start)
    return best


def bench_env(config: Config, num_envs: int, steps: int) -> str:
    """One line: env steps/s at ``num_envs`` parallel envs, and the compile time."""
    env, params = config.make_env()

    def rollout(key):
        k_reset, k_run = jax.random.split(key)
        obs, state = jax.vmap(env.reset, (0, None))(jax.random.split(k_reset, num_envs), params)

        def body(carry, k):
            obs, state = carry
            k_act, k_step = jax.random.split(k)
            actions = jax.random.randint(k_act, (num_envs,), 0, 4)
            obs, state, *_ = jax.vmap(env.step, (0, 0, 0, None))(
                jax.random.split(k_step, num_envs), state, actions, params
            )
            return (obs, state), None

        return jax.lax.scan(body, (obs, state), jax.random.split(k_run, steps))[0]

    key = jax.random.key(0)
    start = time.perf_counter()
    compiled = jax.jit(rollout).lower(key).compile()
    compile_s = time.perf_counter() - start
    run_s = _best_of(lambda: compiled(key))
    return (
        f"env {config['env']['id']}: {num_envs * steps / run_s:,.0f} env steps/s at "
        f"{num_envs} envs ({steps} steps per call, best of 3: {run_s:.3f} s; "
        f"compile {compile_s:.1f} s)"
    )


def bench_train(config: Config, iterations: int) -> str:
    """One line: training iterations/s (env steps, gradient updates) once learning runs."""
    trainer = make_train(config.train_config())
    train_key, _ = config.keys()
    state = init_program(trainer)(train_key)  # train's init program
    start = time.perf_counter()
    run = jax.jit(trainer.run, static_argnums=1).lower(state, iterations).compile()
    compile_s = time.perf_counter() - start
    # fill the replay until learning has started (learning_starts whole episodes)
    while int(state.grad_steps) == 0 and not bool(state.finished):
        state = run(state)
    if bool(state.finished):
        return "train: the run finished before learning started; raise train.num_episodes"
    run_s = _best_of(lambda: run(state))
    train = config["train"]
    n_env, ups = train["num_envs"], train["updates_per_step"]
    return (
        f"train ({config.origin}): {iterations / run_s:,.1f} iterations/s = "
        f"{iterations * n_env / run_s:,.0f} env steps/s and {iterations * ups / run_s:,.1f} "
        f"gradient updates/s (batch {train['batch_size']}×{train['window']}, {n_env} envs; "
        f"compile {compile_s:.1f} s)"
    )
