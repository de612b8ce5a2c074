"""``drqn-jax bench``: the suite of ``benchmarks/`` in a child process, or quick figures (env
steps/s, training throughput, ``study --estimate``), each the best of 3 timed calls after a
warm-up; compile time is reported apart."""

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax

from drqn_jax.config import Config, ConfigError, load_config
from drqn_jax.experiments.machine import machine_info, machine_lines
from drqn_jax.experiments.runner import EXIT_OK, compiled_run, init_program
from drqn_jax.learners import make_train
from drqn_jax.learners.hyperparams import ON_POLICY

#: The suite's benchmarks, in the order ``drqn-jax bench all`` runs them.
SUITE = ("env_throughput", "peers", "train_throughput", "evaluation", "gymnasium_throughput")

#: Benchmarks run by name only, not by ``all`` (long, not throughput figures).
TOOLS = ("gymnax_validation", "learning_curve", "decision_interval", "reward_ranking")


def _run_benchmark(name: str, args: Sequence[str]) -> int:
    """``python -m benchmarks.NAME ARGS`` of this package's clone in a child process."""
    root = Path(__file__).resolve().parents[2]  # the clone: drqn_jax/commands/..
    if not (root / "benchmarks" / "__init__.py").is_file():
        raise ConfigError(
            f"bench {name}: the suite lives in benchmarks/ of a clone of the repository "
            f"(not found beside {Path(__file__).parent}); install with pip install -e ."
        )
    path = os.pathsep.join(p for p in (str(root), os.environ.get("PYTHONPATH")) if p)
    command = [sys.executable, "-m", f"benchmarks.{name}", *args]
    return subprocess.run(command, env={**os.environ, "PYTHONPATH": path}).returncode


def cmd_bench(args: argparse.Namespace) -> int:
    """``quick``, ``all`` (``args.options`` from their parsers) or one benchmark by name."""
    if args.name == "quick":
        quick = args.options
        config = load_config(quick.config, quick.overrides)
        if quick.num_envs < 1 or quick.steps < 1 or quick.iterations < 1:
            raise ConfigError("--num-envs, --steps and --iterations must be >= 1")
        print(bench_env(config, quick.num_envs, quick.steps))
        for k in quick.decision_steps or [None]:
            overrides = [*quick.overrides, f"env.decision_steps={k}"] if k else quick.overrides
            print(bench_train(load_config(quick.config, overrides), quick.iterations))
        print("\n".join(machine_lines(machine_info())))
        return EXIT_OK
    if args.name != "all":
        return _run_benchmark(args.name, args.args)
    options = args.options
    passed = ["--repeats", str(options.repeats)] if options.repeats else []
    passed += ["--out", options.out] if options.out else []
    passed += ["--quick"] if options.quick else []
    status = EXIT_OK
    for name in SUITE:
        print(f"\n# drqn-jax bench {name} {' '.join(passed)}\n", flush=True)
        status = max(status, _run_benchmark(name, passed))
    return status


def _best_of(fn: Callable[[], Any], repeats: int = 3, *, warm_up: bool = True) -> float:
    """The shortest of ``repeats`` timed calls, after an untimed one if ``warm_up``."""
    if warm_up:
        jax.block_until_ready(fn())
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


def _learner_text(config: Config) -> str:
    """What one training iteration of ``config``'s learner holds, in its own terms."""
    train = config["train"]
    if train["algorithm"] in ON_POLICY:
        return (
            f"{train['algorithm'].upper()}: a rollout of {train['rollout_steps']} steps × "
            f"{train['num_envs']} envs, "
            f"{train['update_epochs']} epochs × {train['num_minibatches']} minibatches"
        )
    return (
        f"DQN: {train['num_envs']} envs, {train['updates_per_step']} update(s) of batch "
        f"{train['batch_size']}×{train['window']} per step"
    )


def train_figures(
    config: Config, iterations: int, seeds: int = 1, repeats: int = 3
) -> dict[str, Any] | str:
    """Training throughput once learning runs: ``iterations`` of ``run`` timed (best of
    ``repeats``), env steps and gradient updates counted from the state; ``seeds`` > 1
    ``vmap``-ed as a sweep does. A string says why there is nothing to time."""
    trainer = make_train(config.train_config())
    train_key, _ = config.keys()
    init = init_program(trainer)  # train's init program
    start = time.perf_counter()
    if seeds == 1:  # train's chunk program, ``iterations`` a chunk
        state = init(train_key)
        run = compiled_run(trainer, state, iterations)
    else:
        state = jax.jit(jax.vmap(init))(jax.random.split(train_key, seeds))
        step = jax.vmap(lambda state: trainer.run(state, iterations))
        run = jax.jit(step).lower(state).compile()
    compile_s = time.perf_counter() - start
    # fill the replay until learning has started (the DQN: learning_starts whole episodes)
    while int(state.grad_steps.min()) == 0 and not bool(state.finished.any()):
        state = run(state)
    if int(state.grad_steps.min()) == 0:
        return "the run finished before learning started; raise train.num_episodes"
    after = run(state)
    if bool(after.finished.any()):
        return (
            f"the run's budget ends within {iterations} iterations of learning; raise "
            "train.num_episodes or train.num_env_steps, or lower --iterations"
        )
    return {
        "iterations": iterations,
        "seeds": seeds,
        "num_envs": config["train"]["num_envs"],
        "env_steps": int(after.env_steps.sum()) - int(state.env_steps.sum()),
        "grad_steps": int(after.grad_steps.sum()) - int(state.grad_steps.sum()),
        "seconds": _best_of(lambda: run(state), repeats, warm_up=False),  # ``after`` warmed it up
        "compile_s": compile_s,
    }


def bench_train(config: Config, iterations: int) -> str:
    """One line: :func:`train_figures` as iterations/s, decisions/s (the learner's env steps),
    ticks/s (k = ``env.decision_steps`` a decision; an episode's last may play fewer), updates/s."""
    figures = train_figures(config, iterations)
    if isinstance(figures, str):
        return f"train: {figures}"
    run_s, k = figures["seconds"], config["env"]["decision_steps"]
    decisions = figures["env_steps"] / run_s
    return (
        f"train ({config.origin}, k = {k}): {iterations / run_s:,.1f} iterations/s = "
        f"{decisions:,.0f} decisions/s = {k * decisions:,.0f} ticks/s and "
        f"{figures['grad_steps'] / run_s:,.1f} gradient updates/s "
        f"({_learner_text(config)}; compile {figures['compile_s']:.1f} s)"
    )


def training_estimate(config: Config, runs: int, batched: bool = False) -> dict[str, Any] | str:
    """Seconds to train ``runs`` runs of ``config`` here: their env steps over the measured
    env steps/s (``batched``: ``vmap``-ed, else one run). An episode budget gives an
    ``upper_bound``; compile and evaluation are excluded. A string if nothing to time."""
    train = config["train"]
    figures = train_figures(config, train["chunk_iterations"], runs if batched else 1)
    if isinstance(figures, str):
        return figures
    steps_per_s = figures["env_steps"] / figures["seconds"]
    env = config["env"]
    longest = -(-env["max_steps"] // env["decision_steps"])  # decisions of an episode
    steps = train["num_env_steps"] or train["num_episodes"] * longest
    return {
        "env_steps_per_run": steps,
        "upper_bound": not train["num_env_steps"],
        "env_steps_per_s": steps_per_s,
        "seconds": runs * steps / steps_per_s,
    }


def estimate_lines(arms: Sequence[tuple[str, Config, int, str]]) -> str:
    """Lines of the training wall time on this device of each ``(name, config, runs, sweep
    strategy)`` and, for several, in all (``study --estimate``, ``reproduce --train``): one
    chunk of each timed once learning runs; evaluation and compiles not included."""
    from drqn_jax.commands import duration_text
    from drqn_jax.experiments.sweep_plan import resolve_strategy

    lines, total, bounded, missing = [], 0.0, False, 0
    for name, config, runs, strategy in arms:
        strategy = resolve_strategy(strategy, jax.local_devices())
        figures = training_estimate(config, runs, batched=strategy == "vmap")
        if isinstance(figures, str):
            lines.append(f"{name}: no estimate: {figures}")
            missing += 1
            continue
        total, bounded = total + figures["seconds"], bounded or figures["upper_bound"]
        most = "at most " if figures["upper_bound"] else "about "
        sweep = f"{runs} runs ({strategy}) × " if runs > 1 else ""
        lines.append(
            f"{name} on this {jax.devices()[0].device_kind}: {sweep}{most}"
            f"{figures['env_steps_per_run']:,} env steps at {figures['env_steps_per_s']:,.0f} "
            f"env steps/s: {most}{duration_text(figures['seconds'])}"
        )
    if len(arms) > 1:
        left = f" ({missing} not estimated)" if missing else ""
        lines.append(
            f"training in all: {'at most' if bounded else 'about'} {duration_text(total)}{left}"
        )
    return "\n".join(lines)
