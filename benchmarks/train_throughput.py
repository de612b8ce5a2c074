"""Training throughput: gradient updates/s, env steps/s while learning, compile time, memory.

Usage::

    python -m benchmarks.train_throughput [--runs 1 8] [--updates 50] [--iterations 20]
        [--repeats 5] [--fill-episodes 20] [--out DIR] [--quick]

Measured for the paper preset ``TrainConfig()`` (one env, 200 episodes, replay of
M = 50 episodes, minibatch 32 windows × 8 steps, one gradient update per env
step), for 1 run and for R runs ``jax.vmap``-ed over seeds (``--runs``):

1. **Filling the replay.** Each run is initialised with ``learning_starts``
   raised out of reach and ``trainer.run`` (chunks of 1000 iterations) acts
   until ``--fill-episodes`` training episodes are recorded (the first run;
   the others stop at ``learning_starts`` = 4, to save time); then
   ``learning_starts`` is set back to the preset's 4, so learning is active
   from the next iteration on. Runs are filled one by one, unbatched (under
   ``vmap`` the ``lax.cond`` around learning would compute the update on every
   iteration) and then stacked. The lengths of these episodes (ε ≥ 0.91,
   untrained network, learning off) give the mid-case wall-time estimate, and
   the best 1000-iteration chunk the cost of an iteration before learning starts.
2. **Gradient updates in isolation.** The trainer's own ``gradient_update``
   (``sample_windows`` → ``value_and_grad(sequence_loss)`` → clamp switch →
   Adam → ``apply_updates`` → periodic target copy); ``--updates`` K of them
   in one jitted ``lax.scan``.
3. **End to end.** ``trainer.run(state, --iterations I)`` with learning
   active: I iterations of acting (ε-greedy with the LSTM), env step, replay
   write, one gradient update, episode bookkeeping. The state is donated.
4. **Compile time** of ``trainer.train`` (the whole training program,
   ``jax.jit(trainer.train).lower(key).compile()``, not run) and of the
   programs above (lower + compile, apart from run time).
5. **Memory**: replay bytes (``replay_bytes``), online / target / Adam bytes
   (sum of leaf ``nbytes``), and XLA's ``memory_analysis()`` of the compiled
   ``run`` program (temporaries).

FLOPs per update are counted, not guessed: (a) from the jaxpr of one update,
summing ``2 · MACs`` of every ``dot_general`` and multiplying ``scan`` bodies by
their length (``cond``: the costlier branch); (b) XLA's ``cost_analysis()`` of
the compiled update, which counts every ``while``/``scan`` body ONCE (so the
9-step LSTM unroll counts as one step); (c) an analytic estimate from the
Table I layer sizes. GFLOP/s use (a).

Timing: after one warm-up call, ``--repeats`` timed calls, each continuing from
the previous call's result; the table reports the median, and
the "cores used" (CPU s / wall s) of every timed call goes to stderr.

The paper preset's end-to-end wall time is NOT run; it is estimated from the
measured seconds per iteration (1 run, learning active) times 200 × 1000
iterations (worst case: every episode truncated at max_steps) and times
200 × the mean length of the filled episodes (mid case).

**Every learner, side by side** (``--learners default pqn ppo``, issue 52): each
config's own trainer timed by :func:`drqn_jax.experiments.bench.train_figures`
once learning runs, in env steps per second of learning (env steps and gradient
updates counted from the state, best of 3 calls): the replay DRQN over
``--iterations`` iterations at its own number of envs, an on-policy learner (PQN,
PPO) over ``--rollouts`` rollouts-and-updates at each of ``--envs`` (its own by
default), each with ``--seeds`` S seeds ``jax.vmap``-ed in one program (1 by
default). ``--set`` overrides every learner's config (a lighter network is a
named row: ``--set network.recurrent=64``). Only this table is measured then.

``--quick`` swaps in a tiny network, 30-step episodes and tiny sizes: a smoke
check of the script, not a measurement. ``--out DIR`` writes everything as
``DIR/train_throughput.json`` (and the Markdown as ``.md``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import os
import resource
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.extend.core as jex
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import base_parser, compile_timed, markdown_table, report, time_calls
from drqn_jax.config import Config, load_config
from drqn_jax.experiments.bench import train_figures
from drqn_jax.learners import Hyperparams, TrainConfig, Trainer, make_train
from drqn_jax.learners.dqn.replay import replay_bytes
from drqn_jax.learners.dqn.state import TrainState
from drqn_jax.learners.hyperparams import ON_POLICY
from drqn_jax.networks import NetworkConfig, param_count

TARGET_UPDATES_PER_S = 20.0  # issue 3: gradient updates/s at batch 32 × 8, 2-core CPU
TARGET_REPLAY_MB = 32.0  # issue 3: replay of M = 50 episodes ≤ 32 MB per run
SWEEP_RUNS, SWEEP_GB = 64, 24.0  # ... so that a 64-run sweep fits in 24 GB
NO_LEARNING = 2**30  # learning_starts out of reach while the replay fills
FILL_CHUNK = 1000  # iterations per trainer.run call while filling
MB = 1e6

QUICK_CONFIG = TrainConfig(
    env_overrides=(("max_steps", 30),),
    network=load_config("smoke").network_config(),
    num_episodes=50,
    replay_episodes=8,
    batch_size=4,
    window=4,
    chunk_iterations=16,
)

UpdateCarry = tuple[Any, Any, Any, jax.Array]  # (online, target, opt_state, grad_steps)


# --------------------------------------------------------------------------- FLOP counting

# Elementwise float primitives counted as one operation per output element.
ELEMENTWISE = frozenset(
    {
        *("add", "sub", "mul", "div", "neg", "max", "min", "abs", "sign", "exp", "exp2", "log"),
        *("log1p", "expm1", "tanh", "logistic", "sqrt", "rsqrt", "pow", "integer_pow", "square"),
        *("sin", "cos", "atan2", "floor", "ceil", "round", "select_n", "clamp"),
    }
)


def _sub_jaxprs(value: Any) -> list[jex.Jaxpr]:
    if isinstance(value, jex.ClosedJaxpr):
        return [value.jaxpr]
    if isinstance(value, jex.Jaxpr):
        return [value]
    if isinstance(value, tuple | list):
        return [j for v in value for j in _sub_jaxprs(v)]
    return []


def count_flops(jaxpr: jex.Jaxpr) -> dict[str, float]:
    """Counted FLOPs of a jaxpr: ``matmul`` (2·MACs of dot_general/conv) and ``elementwise``.

    ``scan`` bodies are multiplied by their length, ``cond`` takes its costliest
    branch, a ``while`` body counts once (``while_loops`` says how many there were).
    """
    total = {"matmul": 0.0, "elementwise": 0.0, "while_loops": 0.0}

    def add(counts: dict[str, float], times: float = 1.0) -> None:
        for k, v in counts.items():
            total[k] += times * v

    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        params = eqn.params
        if name == "dot_general":
            (lhs_contract, _), _ = params["dimension_numbers"]
            lhs = eqn.invars[0].aval.shape
            k = math.prod(lhs[d] for d in lhs_contract)
            total["matmul"] += 2.0 * math.prod(eqn.outvars[0].aval.shape) * k
        elif name == "conv_general_dilated":
            rhs = eqn.invars[1].aval.shape  # assumes the default OIHW-like layout spec
            out = math.prod(eqn.outvars[0].aval.shape)
            total["matmul"] += 2.0 * out * math.prod(rhs[1:])
        elif name == "scan":
            add(count_flops(params["jaxpr"].jaxpr), params["length"])
        elif name == "cond":
            branches = [count_flops(b.jaxpr) for b in params["branches"]]
            add(max(branches, key=lambda c: c["matmul"] + c["elementwise"]))
        elif name == "while":
            total["while_loops"] += 1
            add(count_flops(params["body_jaxpr"].jaxpr))
            add(count_flops(params["cond_jaxpr"].jaxpr))
        elif name in ELEMENTWISE:
            if jnp.issubdtype(eqn.outvars[0].aval.dtype, jnp.floating):
                total["elementwise"] += math.prod(eqn.outvars[0].aval.shape)
        else:
            for value in params.values():
                for sub in _sub_jaxprs(value):
                    add(count_flops(sub))
    return total


def analytic_forward_macs(net: NetworkConfig) -> dict[str, int]:
    """Multiply-accumulates of one forward step on one observation, layer by layer."""
    macs: dict[str, int] = {}
    h, w, c = net.grid_shape
    for i, (kh, kw, stride, filters) in enumerate(net.conv):
        h, w = (h - kh) // stride + 1, (w - kw) // stride + 1
        macs[f"conv{i + 1}"] = h * w * kh * kw * c * filters
        c = filters
    width, n_extra = net.recurrent, 1 + net.num_actions
    if net.kind == "drqn":
        gates = 4 if net.cell == "lstm" else 3
        macs[f"{net.cell}1"] = (net.features + width) * gates * width
        macs[f"{net.cell}2"] = (width + n_extra + width) * gates * width
    else:
        macs["dense1"] = net.features * width
        macs["dense2"] = (width + n_extra) * width
    macs["fc"] = width * net.hidden
    macs["q"] = net.hidden * net.num_actions
    return macs


def analytic_update_flops(config: TrainConfig, net: NetworkConfig) -> dict[str, float]:
    """Forward of online and target on (W + 1)·B observations, backward of online ≈ 2× forward."""
    fwd_per_obs = 2.0 * sum(analytic_forward_macs(net).values())
    n_obs = (config.window + 1) * config.batch_size
    forward = 2 * n_obs * fwd_per_obs
    backward = 2 * n_obs * fwd_per_obs
    return {
        "forward_flops_per_obs": fwd_per_obs,
        "obs_per_network": n_obs,
        "forward_flops": forward,
        "backward_flops": backward,
        "total_flops": forward + backward,
    }


def xla_flops(compiled: jax.stages.Compiled) -> float | None:
    """``compiled.cost_analysis()["flops"]`` (a dict, or a list of dicts in older JAX)."""
    try:
        ca = compiled.cost_analysis()
    except Exception:  # not every backend implements it
        return None
    if isinstance(ca, list | tuple):
        ca = ca[0] if ca else {}
    return None if not ca or "flops" not in ca else float(ca["flops"])


def memory_of(compiled: jax.stages.Compiled) -> dict[str, float] | None:
    """XLA's memory analysis of a compiled program, in MB."""
    try:
        m = compiled.memory_analysis()
    except Exception:
        return None
    if m is None:
        return None
    names = ("argument", "output", "alias", "temp", "generated_code")
    return {f"{n}_mb": getattr(m, f"{n}_size_in_bytes") / MB for n in names}


# --------------------------------------------------------------------------- pieces


def tree_bytes(tree: Any) -> int:
    return sum(int(x.nbytes) for x in jax.tree.leaves(tree))


def stack(trees: Sequence[Any]) -> Any:
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def batched(fn: Callable, runs: int, in_axes: Any = 0) -> Callable:
    """``fn`` itself for one run, ``jax.vmap(fn, in_axes)`` for several."""
    return fn if runs == 1 else jax.vmap(fn, in_axes=in_axes)


def update_args(trainer: Trainer, state: TrainState, key: jax.Array) -> tuple:
    """The arguments of ``trainer.gradient_update`` taken from ``state``:
    ``((online, target, opt_state, grad_steps), key, replay, hparams, env_params)``."""
    learner = (state.online, state.target, state.opt_state, state.grad_steps)
    return learner, key, state.replay, state.hparams, trainer.env_params


def make_updates(update: Callable, num_updates: int) -> Callable:
    """``num_updates`` updates in one ``lax.scan`` (fresh windows each)."""

    def updates(
        carry: UpdateCarry, key: jax.Array, replay: Any, hp: Hyperparams, env_params: Any
    ) -> tuple[UpdateCarry, jax.Array]:
        def body(c: UpdateCarry, k: jax.Array) -> tuple[UpdateCarry, jax.Array]:
            return update(c, k, replay, hp, env_params)

        return jax.lax.scan(body, carry, jax.random.split(key, num_updates))

    return updates


def fill_replay(
    trainer: Trainer, key: jax.Array, episodes: int, fill_run: Callable
) -> tuple[TrainState, dict[str, Any]]:
    """One run acting with learning off until ``episodes`` are recorded; then learning on."""
    hp = trainer.config.hyperparams
    start = time.perf_counter()
    state = jax.jit(trainer.init)(key, hp.replace(learning_starts=NO_LEARNING))
    chunk_times = []
    while int(state.recorded) < episodes:
        t = time.perf_counter()
        state = jax.block_until_ready(fill_run(state, FILL_CHUNK))
        chunk_times.append(time.perf_counter() - t)
    seconds = time.perf_counter() - start
    recorded = int(state.recorded)
    complete = int(jnp.sum(state.replay.complete))
    if complete < int(hp.learning_starts):
        raise RuntimeError(
            f"replay holds {complete} complete episodes, fewer than learning_starts = "
            f"{int(hp.learning_starts)}: raise --fill-episodes"
        )
    state = state.replace(hparams=state.hparams.replace(learning_starts=hp.learning_starts))
    metrics = {k: np.asarray(v[:recorded]) for k, v in state.metrics.items()}
    info = {
        "seconds": seconds,
        "chunk_iterations": FILL_CHUNK,
        "chunk_times_s": chunk_times,
        "env_steps": int(state.env_steps),
        "recorded": recorded,
        "complete_in_replay": complete,
        "lengths": metrics["length"].tolist(),
        "epsilons": metrics["epsilon"].tolist(),
        "goals": int(np.sum(metrics["goal"])),
        "collisions": int(np.sum(metrics["collision"])),
    }
    return state, info


# --------------------------------------------------------------------------- one run count


def bench_runs(
    trainer: Trainer,
    runs: int,
    fills: list[tuple[TrainState, dict[str, Any]]],
    args: argparse.Namespace,
    update_flops: float,
    iteration_flops: float,
) -> dict[str, Any]:
    """All figures for ``runs`` runs (vmapped when > 1), from already-filled states."""
    row: dict[str, Any] = {"runs": runs}
    # a copy: the state is donated below, and the filled states serve every run count
    state = stack([s for s, _ in fills[:runs]]) if runs > 1 else jax.tree.map(jnp.copy, fills[0][0])
    keys = jax.random.split(jax.random.key(args.seed + 1), runs)
    key = keys[0] if runs == 1 else keys

    # memory per run (from the live state)
    one = fills[0][0]
    row["memory"] = {
        "replay_mb_per_run": replay_bytes(one.replay) / MB,
        "params_mb_per_run": tree_bytes(one.online) / MB,
        "target_mb_per_run": tree_bytes(one.target) / MB,
        "adam_mb_per_run": tree_bytes(one.opt_state) / MB,
        "train_state_mb_per_run": tree_bytes(one) / MB,
        "train_state_mb_total": tree_bytes(state) / MB,
    }

    # (a) gradient updates in isolation
    update = trainer.gradient_update
    updates = batched(make_updates(update, args.updates), runs, (0, 0, 0, 0, None))
    carry, _, *statics = update_args(trainer, state, key)
    compiled, lower_s, xla_s = compile_timed(jax.jit(updates), carry, key, *statics)
    before = np.asarray(carry[3]).copy()
    carry, t = time_calls(lambda c: compiled(c, key, *statics)[0], carry, args.repeats)
    done = int(np.sum(np.asarray(carry[3]) - before))
    expected = runs * args.updates * (args.repeats + 1)
    if done != expected:
        raise RuntimeError(f"update benchmark: {done} gradient steps, expected {expected}")
    per_run = args.updates / t["run_s"]
    row["updates"] = {
        **t,
        "updates_per_call": args.updates,
        "lower_s": lower_s,
        "xla_compile_s": xla_s,
        "compile_s": lower_s + xla_s,
        "updates_per_s_per_run": per_run,
        "updates_per_s_total": runs * per_run,
        "ms_per_update_per_run": 1e3 / per_run,
        "gflops_per_s": runs * per_run * update_flops / 1e9,
        "xla_cost_analysis_flops_of_program": xla_flops(compiled),
        "xla_memory": memory_of(compiled),
        "finite_loss_after": bool(jnp.all(jnp.isfinite(compiled(carry, key, *statics)[1]))),
    }
    print(
        f"[{runs} run(s), updates: compile {lower_s + xla_s:.2f} s, best {t['run_s']:.3f} s "
        f"per {args.updates}, {runs * per_run:.2f} updates/s total, cores used per timed call "
        f"{', '.join(f'{c:.2f}' for c in t['cores_used_per_call'])}]",
        file=sys.stderr,
        flush=True,
    )

    # (b) end to end: trainer.run with learning active
    run_n = batched(functools.partial(trainer.run, num_iterations=args.iterations), runs)
    jitted = jax.jit(run_n, donate_argnums=0)
    compiled, lower_s, xla_s = compile_timed(jitted, state)
    g0, e0 = np.asarray(state.grad_steps).copy(), np.asarray(state.env_steps).copy()
    state, t = time_calls(compiled, state, args.repeats)
    calls = args.repeats + 1
    grad_done = int(np.sum(np.asarray(state.grad_steps) - g0))
    env_done = int(np.sum(np.asarray(state.env_steps) - e0))
    n_env = trainer.config.num_envs
    if env_done != runs * args.iterations * calls * n_env:
        raise RuntimeError(f"run benchmark: {env_done} env steps, expected more (finished?)")
    if grad_done != runs * args.iterations * calls * trainer.config.updates_per_step:
        raise RuntimeError(f"run benchmark: {grad_done} gradient steps: learning not active?")
    iters_per_s = args.iterations / t["run_s"]
    row["run"] = {
        **t,
        "iterations_per_call": args.iterations,
        "lower_s": lower_s,
        "xla_compile_s": xla_s,
        "compile_s": lower_s + xla_s,
        "iterations_per_s_per_run": iters_per_s,
        "s_per_iteration": 1.0 / iters_per_s,
        "env_steps_per_s_per_run": iters_per_s * n_env,
        "env_steps_per_s_total": runs * iters_per_s * n_env,
        "updates_per_s_total": runs * iters_per_s * trainer.config.updates_per_step,
        "gflops_per_s": runs * iters_per_s * iteration_flops / 1e9,
        "gradient_steps_done": grad_done,
        "env_steps_done": env_done,
        "xla_memory": memory_of(compiled),
    }
    print(
        f"[{runs} run(s), trainer.run: compile {lower_s + xla_s:.2f} s, best {t['run_s']:.3f} s "
        f"per {args.iterations} iterations, {runs * iters_per_s:.2f} env steps/s total, cores "
        f"used per timed call {', '.join(f'{c:.2f}' for c in t['cores_used_per_call'])}]",
        file=sys.stderr,
        flush=True,
    )

    # (c) compile time of the whole training program (not run)
    train = jax.jit(batched(trainer.train, runs))
    _, lower_s, xla_s = compile_timed(train, key)
    row["train_compile"] = {
        "lower_s": lower_s,
        "xla_compile_s": xla_s,
        "compile_s": lower_s + xla_s,
    }
    print(
        f"[{runs} run(s), trainer.train: lower {lower_s:.2f} s + compile {xla_s:.2f} s]",
        file=sys.stderr,
        flush=True,
    )
    return row


# --------------------------------------------------------------------------- output


def verdict(ok: bool) -> str:
    return "meets target" if ok else "MISSES target"


def report_lines(result: dict[str, Any]) -> list[str]:
    """Markdown tables and summary lines."""
    rows, flops, cfg = result["rows"], result["flops"], result["config"]
    k, it = cfg["updates"], cfg["iterations"]
    bw = f"{cfg['batch_size']} × {cfg['window']}"
    out = [
        f"### Gradient updates in isolation (batch {bw}, {k} updates per call in one lax.scan)",
        "",
        "| runs | compile s | median s per call | updates/s (all runs) | updates/s per run "
        "| ms per update (per run) | GFLOP/s (counted) |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        u = r["updates"]
        out.append(
            f"| {r['runs']} | {u['compile_s']:.2f} | {u['run_s']:.3f} "
            f"| {u['updates_per_s_total']:.2f} | {u['updates_per_s_per_run']:.2f} "
            f"| {u['ms_per_update_per_run']:.1f} | {u['gflops_per_s']:.1f} |"
        )
    out += [
        "",
        f"### End to end: `trainer.run`, learning active ({it} iterations per call; "
        "1 iteration = 1 env step + 1 update per run)",
        "",
        "| runs | compile s | median s per call | iterations/s per run | s per iteration "
        "| env steps/s (all runs) | updates/s (all runs) | GFLOP/s (counted) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        u = r["run"]
        out.append(
            f"| {r['runs']} | {u['compile_s']:.2f} | {u['run_s']:.3f} "
            f"| {u['iterations_per_s_per_run']:.2f} | {u['s_per_iteration']:.3f} "
            f"| {u['env_steps_per_s_total']:.2f} | {u['updates_per_s_total']:.2f} "
            f"| {u['gflops_per_s']:.1f} |"
        )
    out += [
        "",
        "### Compile time (lower + XLA compile, s)",
        "",
        "| runs | `trainer.train` (whole run) | `trainer.run` | K updates |",
        "|---:|---:|---:|---:|",
    ]
    for r in rows:
        out.append(
            f"| {r['runs']} | {r['train_compile']['compile_s']:.2f} "
            f"({r['train_compile']['lower_s']:.2f} + {r['train_compile']['xla_compile_s']:.2f}) "
            f"| {r['run']['compile_s']:.2f} | {r['updates']['compile_s']:.2f} |"
        )
    out += [
        "",
        "### Memory (MB = 10^6 bytes)",
        "",
        "| runs | replay per run | online + target + Adam per run | whole TrainState (all runs) "
        "| XLA temporaries of `trainer.run` (all runs) | per run: state + temporaries |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        m = r["memory"]
        nets = m["params_mb_per_run"] + m["target_mb_per_run"] + m["adam_mb_per_run"]
        xm = r["run"]["xla_memory"]
        temp = xm["temp_mb"] if xm else float("nan")
        per_run = m["train_state_mb_total"] / r["runs"] + temp / r["runs"]
        out.append(
            f"| {r['runs']} | {m['replay_mb_per_run']:.2f} | {nets:.2f} "
            f"({m['params_mb_per_run']:.2f} + {m['target_mb_per_run']:.2f} + "
            f"{m['adam_mb_per_run']:.2f}) | {m['train_state_mb_total']:.2f} | {temp:.2f} "
            f"| {per_run:.2f} |"
        )

    a = flops["analytic"]
    out += [
        "",
        "### FLOPs per gradient update",
        "",
        f"- counted from the jaxpr of one update (2·MACs of every dot_general, scan bodies × "
        f"length): **{flops['update_counted']['matmul'] / 1e9:.3f} GFLOP** of matmul, plus "
        f"{flops['update_counted']['elementwise'] / 1e9:.3f} G elementwise float ops "
        f"(not in GFLOP/s); {flops['update_counted']['while_loops']:.0f} while loops "
        "(counted once each)",
        "- XLA `cost_analysis()` of one compiled update: "
        + (
            f"{flops['update_xla'] / 1e9:.3f} GFLOP"
            if flops["update_xla"] is not None
            else "(not available)"
        )
        + f" (counts each scan/while body once: the {cfg['window'] + 1}-step LSTM unroll as 1 "
        "step; counts elementwise ops as FLOPs too)",
        f"- analytic (Table I): {a['forward_flops_per_obs'] / 1e6:.3f} MFLOP forward per "
        f"observation ({' + '.join(f'{n} {m / 1e3:.1f}k' for n, m in flops['macs'].items())} "
        f"MACs × 2); 2 networks × {a['obs_per_network']} observations forward "
        f"({a['forward_flops'] / 1e9:.3f} GFLOP) + backward of the online net ≈ 2× its forward "
        f"({a['backward_flops'] / 1e9:.3f} GFLOP) = **{a['total_flops'] / 1e9:.3f} GFLOP**",
        f"- one `trainer.run` iteration with learning active, counted the same way: "
        f"{flops['iteration_counted']['matmul'] / 1e9:.3f} GFLOP of matmul "
        f"(network parameters: {flops['param_count']:,})",
    ]

    one = next((r for r in rows if r["runs"] == 1), rows[0])
    s = result["summary"]
    out += [
        "",
        "### Against the targets (issue 3)",
        "",
        f"- gradient updates/s at batch {bw}, 1 run: {one['updates']['updates_per_s_per_run']:.2f}"
        f" (target: >= {TARGET_UPDATES_PER_S:g} on the 2-core CPU; "
        f"{verdict(s['meets_updates_target'])})",
        f"- replay per run: {one['memory']['replay_mb_per_run']:.2f} MB "
        f"(target: <= {TARGET_REPLAY_MB:g} MB for M = 50 episodes of up to 1000 steps; "
        f"{verdict(s['meets_replay_target'])})",
    ]
    if s.get("sweep_gb_estimate") is not None:
        out.append(
            f"- {SWEEP_RUNS}-run sweep, estimated as {SWEEP_RUNS} × (state + temporaries per run "
            f"at {s['sweep_basis_runs']} runs): {s['sweep_gb_estimate']:.2f} GB (target: fits in "
            f"{SWEEP_GB:g} GB; {verdict(s['sweep_gb_estimate'] <= SWEEP_GB)})"
        )

    e = result["estimate"]
    out += [
        "",
        "### Paper preset end-to-end wall time (ESTIMATE, not run)",
        "",
        f"- measured: {e['s_per_iteration']:.3f} s per iteration (1 run, learning active)"
        + (
            f"; {1e3 * e['acting_only_s_per_iteration']:.2f} ms per iteration before learning "
            f"starts (acting only: best {FILL_CHUNK}-iteration chunk while filling)"
            if e["acting_only_s_per_iteration"] is not None
            else ""
        ),
        f"- worst case, {e['episodes']} × {e['max_steps']} iterations (every episode truncated): "
        f"**{e['worst_case_h']:.1f} h** (estimate)",
        f"- mid case, {e['episodes']} × {e['mean_length']:.1f} iterations (mean length of the "
        f"{e['length_episodes']} filled episodes of {e['runs_filled']} run(s): "
        f"ε ≥ {e['min_epsilon']:.2f}, learning off, untrained network): "
        f"**{e['mid_case_h']:.1f} h** (estimate; later episodes, with ε down to 0.1 and a "
        "trained policy, may be longer or shorter)",
        f"- lengths of the filled episodes: min {e['min_length']}, max {e['max_length']}, "
        f"{e['truncated']} of {e['length_episodes']} reached max_steps; "
        f"{e['goals']} goals, {e['collisions']} collisions",
    ]
    return out


# --------------------------------------------------------------------------- every learner

#: ``--quick``: each learner's algorithm on ``smoke``'s tiny world and network.
QUICK_LEARNER = {
    "dqn": [],
    "ppo": ["train.rollout_steps=8", "train.num_minibatches=1"],
    "pqn": ["train.rollout_steps=8", "train.num_minibatches=1", "network.layer_norm=true"],
}

LEARNER_COLUMNS = {
    "learner": "config",
    "algorithm": "learner",
    "num_envs": "envs per seed",
    "seeds": "seeds (vmap)",
    "env_steps_per_s": "env steps/s of learning (all seeds)",
    "grad_steps_per_s": "gradient updates/s",
    "compile_s": "compile s",
}


def learner_config(
    name: str, overrides: Sequence[str], envs: int | None, calls: int, quick: bool
) -> Config:
    """``name`` with ``overrides`` (``quick``: its algorithm on ``smoke``); an on-policy
    learner at ``envs`` envs (None: its own) with a step budget that outlasts ``calls``
    rollouts. The replay DRQN keeps its own envs and budget."""
    config = load_config(name, overrides)
    if quick:
        algorithm = config["train"]["algorithm"]
        extra = [f"train.algorithm={algorithm}", *QUICK_LEARNER[algorithm]]
        name, overrides = "smoke", [*extra, *overrides]
        config = load_config(name, overrides)
    train = config["train"]
    if train["algorithm"] not in ON_POLICY:
        return config
    envs = train["num_envs"] if envs is None else envs
    steps = calls * train["rollout_steps"] * envs
    sized = [f"train.num_envs={envs}", f"train.num_env_steps={steps}"]
    sized += [f"train.num_episodes={max(train['num_episodes'], steps // 10)}"]
    return load_config(name, [*overrides, *sized])


def learner_rows(args: argparse.Namespace) -> list[dict[str, Any]]:
    """One row per learner × envs × seeds: :func:`train_figures` in rates."""
    rows = []
    for name in args.learners:
        on_policy = load_config(name, args.set)["train"]["algorithm"] in ON_POLICY
        for envs in (args.envs or [None]) if on_policy else [None]:
            for seeds in args.seeds:
                iterations = args.rollouts if on_policy else args.iterations
                config = learner_config(name, args.set, envs, 6 * iterations, args.quick)
                figures = train_figures(config, iterations, seeds)
                if isinstance(figures, str):
                    raise SystemExit(f"{name} at {envs} envs: {figures}")
                seconds = figures["seconds"]
                rows.append(
                    {
                        "learner": name,
                        "algorithm": config["train"]["algorithm"],
                        **figures,
                        "env_steps_per_s": figures["env_steps"] / seconds,
                        "grad_steps_per_s": figures["grad_steps"] / seconds,
                        "overrides": args.set,
                    }
                )
                print(rows[-1], file=sys.stderr, flush=True)
    return rows


def learners_main(args: argparse.Namespace, argv: Sequence[str] | None) -> dict[str, Any]:
    """``--learners``: the side-by-side table of every learner's learning throughput."""
    start = time.perf_counter()
    rows = learner_rows(args)
    fastest = max(rows, key=lambda r: r["env_steps_per_s"])
    lines = [
        "Env steps per second of learning (best of 3 calls once learning runs; env steps "
        "and gradient updates counted from the training state). Replay DRQN: "
        f"{args.iterations} iterations per call; PQN and PPO: {args.rollouts} "
        "rollout(s) and their update epochs per call."
        + (f" Overrides: {' '.join(args.set)}." if args.set else ""),
        "",
        *markdown_table(rows, LEARNER_COLUMNS),
        "",
        f"Fastest: `{fastest['learner']}` ({fastest['algorithm']}) at {fastest['num_envs']} "
        f"envs × {fastest['seeds']} seed(s).",
    ]
    result = {"rows": rows, "wall_s": time.perf_counter() - start, "quick": args.quick}
    title = "Learning throughput of every learner" + (" (QUICK: tiny sizes)" if args.quick else "")
    return report("train_throughput", title, result, lines, args.out, argv)


# --------------------------------------------------------------------------- main


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = base_parser("train_throughput", __doc__)
    parser.add_argument(
        "--runs",
        type=int,
        nargs="+",
        default=[1, 8],
        metavar="R",
        help="numbers of vmapped runs (default: 1 8)",
    )
    parser.add_argument(
        "--updates", type=int, default=50, metavar="K", help="updates per timed call (default 50)"
    )
    parser.add_argument(
        "--iterations",
        type=int,
        default=20,
        metavar="I",
        help="trainer.run iterations per timed call (default 20)",
    )
    parser.add_argument(
        "--fill-episodes",
        type=int,
        default=20,
        metavar="E",
        help="episodes the first run records before timing, learning off; the others record "
        "learning_starts (default 20)",
    )
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument(
        "--learners",
        nargs="+",
        metavar="CONFIG",
        help="time these configs' learners side by side instead (e.g. default pqn ppo)",
    )
    parser.add_argument(
        "--envs", type=int, nargs="+", metavar="N", help="--learners: on-policy envs per seed"
    )
    parser.add_argument(
        "--seeds", type=int, nargs="+", default=[1], metavar="S", help="--learners: vmapped seeds"
    )
    parser.add_argument(
        "--rollouts", type=int, default=1, metavar="R", help="--learners: on-policy per call"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="--learners: override every learner's config",
    )
    parser.add_argument(
        "--quick", action="store_true", help="tiny network and sizes: a smoke check only"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.updates, args.iterations, args.repeats = 3, 5, 1
        args.fill_episodes = min(args.fill_episodes, 6)
    values = (args.updates, args.iterations, args.repeats, args.fill_episodes, *args.runs)
    values += (args.rollouts, *args.seeds, *(args.envs or ()))
    if min(values) < 1:
        parser.error(
            "--runs, --updates, --iterations, --repeats, --fill-episodes, --rollouts, --seeds, "
            "--envs must be >= 1"
        )
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    if args.learners:
        return learners_main(args, argv)
    config = QUICK_CONFIG if args.quick else TrainConfig()
    if args.fill_episodes >= config.num_episodes:
        raise SystemExit("--fill-episodes must be below the preset's num_episodes")
    trainer = make_train(config)
    net = trainer.network.config
    max_runs = max(args.runs)
    wall_start = time.perf_counter()

    title = "QUICK SMOKE CHECK (tiny network; not a measurement)" if args.quick else "paper preset"
    setup = (
        f"TrainConfig: num_envs={config.num_envs}, num_episodes={config.num_episodes}, "
        f"replay_episodes={config.replay_episodes}, batch_size={config.batch_size}, "
        f"window={config.window}, updates_per_step={config.updates_per_step}, "
        f"env max_steps={trainer.env.static.max_steps}, network {net.kind} "
        f"(conv {net.conv}, recurrent {net.recurrent}, hidden {net.hidden}). "
        f"Each run's replay first filled (learning off) until it has recorded "
        f"{args.fill_episodes} episodes (run 0) or learning_starts = "
        f"{int(config.hyperparams.learning_starts)} (other runs), then learning on. "
        f"Median of {args.repeats} timed calls after 1 warm-up; "
        "compile s = lower + XLA compile. Runs > 1 are jax.vmap-ed over seeds."
    )
    print(setup, file=sys.stderr, flush=True)

    # fill the replays, one run at a time
    fill_run = jax.jit(trainer.run, static_argnums=1, donate_argnums=0)
    fills = []
    for i, key in enumerate(jax.random.split(jax.random.key(args.seed), max_runs)):
        episodes = args.fill_episodes if i == 0 else int(config.hyperparams.learning_starts)
        fills.append(fill_replay(trainer, key, episodes, fill_run))
        f = fills[-1][1]
        print(
            f"[fill run {i}: {f['recorded']} episodes, {f['env_steps']} env steps, "
            f"{f['seconds']:.1f} s{' (compile included)' if i == 0 else ''}, "
            f"{FILL_CHUNK}-iteration chunks took "
            f"{', '.join(f'{c:.2f}' for c in f['chunk_times_s'])} s, mean length "
            f"{np.mean(f['lengths']):.1f}]",
            file=sys.stderr,
            flush=True,
        )

    # counted FLOPs (unbatched: one run)
    one = fills[0][0]
    update = trainer.gradient_update
    upd_args = update_args(trainer, one, jax.random.key(0))
    update_counted = count_flops(jax.make_jaxpr(update)(*upd_args).jaxpr)
    iteration_counted = count_flops(jax.make_jaxpr(lambda s: trainer.run(s, 1))(one).jaxpr)
    update_xla = xla_flops(jax.jit(update).lower(*upd_args).compile())
    flops = {
        "update_counted": update_counted,
        "update_xla": update_xla,
        "iteration_counted": iteration_counted,
        "analytic": analytic_update_flops(config, net),
        "macs": analytic_forward_macs(net),
        "param_count": param_count(one.online),
    }

    rows = [
        bench_runs(trainer, r, fills, args, update_counted["matmul"], iteration_counted["matmul"])
        for r in args.runs
    ]

    # summary and estimates
    one_row = next((r for r in rows if r["runs"] == 1), rows[0])
    multi = max(rows, key=lambda r: r["runs"])
    summ: dict[str, Any] = {
        "meets_updates_target": one_row["updates"]["updates_per_s_per_run"] >= TARGET_UPDATES_PER_S,
        "meets_replay_target": one_row["memory"]["replay_mb_per_run"] <= TARGET_REPLAY_MB,
        "target_updates_per_s": TARGET_UPDATES_PER_S,
        "target_replay_mb": TARGET_REPLAY_MB,
        "sweep_gb_estimate": None,
        "sweep_basis_runs": multi["runs"],
    }
    if multi["run"]["xla_memory"]:
        per_run_mb = (
            multi["memory"]["train_state_mb_total"] + multi["run"]["xla_memory"]["temp_mb"]
        ) / multi["runs"]
        summ["sweep_gb_estimate"] = SWEEP_RUNS * per_run_mb / 1e3
    lengths = np.concatenate([np.asarray(f["lengths"]) for _, f in fills])
    epsilons = np.concatenate([np.asarray(f["epsilons"]) for _, f in fills])
    # acting only (learning off): the best fill chunk, the first one (compile) left out
    chunks = [c for _, f in fills for c in f["chunk_times_s"]][1:]
    max_steps = trainer.env.static.max_steps
    s_per_it = one_row["run"]["s_per_iteration"]
    n_episodes = config.num_episodes
    estimate = {
        "s_per_iteration": s_per_it,
        "episodes": n_episodes,
        "max_steps": max_steps,
        "worst_case_iterations": n_episodes * max_steps,
        "worst_case_h": n_episodes * max_steps * s_per_it / 3600,
        "mean_length": float(np.mean(lengths)),
        "mid_case_iterations": n_episodes * float(np.mean(lengths)),
        "mid_case_h": n_episodes * float(np.mean(lengths)) * s_per_it / 3600,
        "length_episodes": int(lengths.size),
        "min_epsilon": float(epsilons.min()),
        "runs_filled": len(fills),
        "acting_only_s_per_iteration": min(chunks) / FILL_CHUNK if chunks else None,
        "min_length": int(lengths.min()),
        "max_length": int(lengths.max()),
        "truncated": int(np.sum(lengths >= max_steps)),
        "goals": sum(f["goals"] for _, f in fills),
        "collisions": sum(f["collisions"] for _, f in fills),
    }
    result = {
        "config": {
            "quick": args.quick,
            "runs": args.runs,
            "updates": args.updates,
            "iterations": args.iterations,
            "repeats": args.repeats,
            "fill_episodes": args.fill_episodes,
            "seed": args.seed,
            "batch_size": config.batch_size,
            "window": config.window,
            "train_config": {
                k: v for k, v in dataclasses.asdict(config).items() if k != "hyperparams"
            },
        },
        "fills": [f for _, f in fills],
        "flops": flops,
        "rows": rows,
        "summary": summ,
        "estimate": estimate,
        "wall_s": time.perf_counter() - wall_start,
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / MB,
        "loadavg_1min_at_end": os.getloadavg()[0],
    }

    lines = [
        setup,
        "",
        *report_lines(result),
        "",
        f"(benchmark wall time {result['wall_s']:.0f} s; peak RSS of the process "
        f"{result['max_rss_mb']:.0f} MB; load average (1 min) at end "
        f"{result['loadavg_1min_at_end']:.2f})",
    ]
    title = "DRQN training throughput, " + title
    return report("train_throughput", title, result, lines, args.out, argv)


if __name__ == "__main__":
    main()
