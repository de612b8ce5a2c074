"""Each stage of the env step alone, against the number of envs: where a step's time goes.

Usage::

    python -m benchmarks.stages [--batch-sizes 1 64 4096 65536] [--steps T] [--repeats N]
        [--warmup-steps W] [--out DIR] [--quick]

For every number of envs N and every stage, ONE jitted program runs ``lax.scan``
over T steps of ``jax.vmap`` of that stage alone on N env states, like
``benchmarks/env_throughput.py`` does for the whole step. The stages, as
``UrbanPedestrians.step`` runs them (``drqn_jax/env/urban.py``):

* **ego**: action → setpoint → PID → plant (``ego_step``); the action cycles
  through the four actions, different per env (no random draw);
* **pedestrians**: ``step_pedestrians``, then ``despawn_mask`` and
  ``respawn_pedestrians`` with a fresh key per env and step (P new
  pedestrians drawn in the envs where one is gone, and taken there; the
  draw is skipped elsewhere), as ``UrbanPedestrians._next_state``
  does while the episode goes on; the ego drives on meanwhile (``s += v·dt``);
* **grid**: ``rasterize_grid`` → the (45, 30, 4) float32 observation grid;
* **TTC**: ``time_to_collision``;
* **reward**: ``collision`` and ``reward``;
* **full step**: ``env.step`` with same-step auto-reset and random actions,
  the rollout of ``benchmarks/env_throughput.py`` itself, for reference.

The states are realistic: N envs are reset and the full-step rollout (a jitted
program) runs ``--warmup-steps`` random steps first; every stage starts from the
resulting states (a copy each, since carries are donated).

Nothing is computed for nothing. Every stage's output is in the scan carry and
the final carry is returned, so XLA cannot drop it: the pedestrian update and
the ego step carry their state forward; the grid carries the last grid; TTC
carries the running minimum, reward the running sum. Inputs change every
step, so XLA cannot hoist the stage out of the loop: the grid, TTC and reward
stages are fed a *drifting* state (the ego moves by ``v·dt`` with a sawtooth
speed, the pedestrians by ``velocity·dt``, those that fall behind the grid
window wrap to its front), and the reward's TTC input counts down. That
drift is timed alone as the **drift** row, the overhead inside those three
rows (not subtracted).

Reported per stage and N: compile s (lower + XLA compile), run s (MEDIAN of
``--repeats`` timed calls after one warm-up, each continuing from the last
carry), env steps/s, ns per env-step and the stage's share of the full
step's time at the same N. Every program pays a fixed cost per scan
iteration (a few µs on XLA:CPU), so at small N each row is mostly that cost:
the stages' shares then add up to well over 1, and a light stage can even
take longer than the full step. Read the shares at large N. ``--quick``: N =
64, T = 10, 2 repeats: a smoke check of the script, not a measurement.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

import drqn_jax
from benchmarks.env_throughput import ENV_ID, QUICK_ENVS, QUICK_STEPS, time_rollout
from benchmarks.harness import base_parser, compile_timed, markdown_table, report, time_calls
from drqn_jax.env.collision import classify_hits, time_to_collision
from drqn_jax.env.ego import ego_step
from drqn_jax.env.grid import rasterize_grid
from drqn_jax.env.pedestrians import despawn_mask, respawn_pedestrians, step_pedestrians
from drqn_jax.env.reward import reward as compute_reward
from drqn_jax.env.state import NUM_ACTIONS, EgoState, EnvState, PedestrianState

__all__ = ["DEFAULT_BATCH_SIZES", "STAGE_NAMES", "Stage", "bench_batch", "main", "make_stages"]

DEFAULT_BATCH_SIZES = (1, 64, 4096, 65536)
QUICK_BATCH_SIZES = (QUICK_ENVS,)
FULL = "full step"
# Order of the table; "drift" is the input driver of grid, TTC and reward.
STAGE_NAMES = ("ego", "pedestrians", "grid", "TTC", "reward", "drift", FULL)
# The stages whose times make up a step (the drift is not one).
STEP_STAGES = ("ego", "pedestrians", "grid", "TTC", "reward")
SAWTOOTH_DV = 0.05  # m/s added to the drifting ego's speed per step, wrapped at the limit

Params = drqn_jax.EnvParams


class Stage(NamedTuple):
    """One stage: ``init(state, key, params) -> carry`` (not timed) and ``step(carry, t, params)
    -> carry`` (one step of N envs, ``t`` the step index within the call)."""

    name: str
    what: str
    init: Callable[[EnvState, jax.Array, Params], Any]
    step: Callable[[Any, jax.Array, Params], Any]


# --------------------------------------------------------------------------- the drift


def drift_ego(ego: EgoState, params: Params) -> EgoState:
    """One env's ego moved by ``v·dt``; its speed a sawtooth in [0, max_vehicle_speed)."""
    v = ego.v + SAWTOOTH_DV
    v = jnp.where(v >= params.max_vehicle_speed, 0.0, v)
    return ego.replace(s=ego.s + ego.v * params.dt, v=v.astype(jnp.float32))


def drift(
    ego: EgoState, peds: PedestrianState, params: Params, static: drqn_jax.StaticEnvParams
) -> tuple[EgoState, PedestrianState]:
    """One env's ego and pedestrians moved on (a cheap stand-in for the dynamics that keeps
    the pedestrians around the grid window): pedestrians by ``velocity·dt``, and those
    behind the window's rear edge moved forward by its length."""
    ego = drift_ego(ego, params)
    x = peds.position[:, 0] + peds.velocity[:, 0] * params.dt
    y = peds.position[:, 1] + peds.velocity[:, 1] * params.dt
    window = static.grid_rows * static.cell_size
    x = jnp.where(x < ego.s + static.grid_x_min, x + window, x)
    return ego, peds.replace(position=jnp.stack([x, y], axis=-1))


# --------------------------------------------------------------------------- the stages


def make_stages(env: drqn_jax.UrbanPedestrians, num_envs: int) -> dict[str, Stage]:
    """The stages (but the full step) for ``num_envs`` envs, keyed by name."""
    static = env.static
    vmap = jax.vmap

    def ego_init(state: EnvState, key: jax.Array, params: Params) -> EgoState:
        return state.ego

    def ego_stage(ego: EgoState, t: jax.Array, params: Params) -> EgoState:
        actions = (jnp.arange(num_envs, dtype=jnp.int32) + t) % NUM_ACTIONS
        return vmap(ego_step, (0, 0, None))(ego, actions, params)

    def peds_init(state: EnvState, key: jax.Array, params: Params) -> tuple:
        return state.ego, state.pedestrians, key

    def one_env_peds(
        key: jax.Array, ego: EgoState, peds: PedestrianState, params: Params
    ) -> PedestrianState:
        # As UrbanPedestrians.advance + _next_state while the episode goes on (no reset).
        peds = step_pedestrians(peds, ego, params)
        gone = despawn_mask(peds, ego, params)
        lo, hi = env._spawn_range(ego.s, params, jnp.asarray(False))
        return respawn_pedestrians(key, peds, gone, lo, hi, params, static)

    def peds_stage(carry: tuple, t: jax.Array, params: Params) -> tuple:
        ego, peds, key = carry
        key, step_key = jax.random.split(key)
        ego = vmap(drift_ego, (0, None))(ego, params)  # the ego drives on
        keys = jax.random.split(step_key, num_envs)
        peds = vmap(one_env_peds, (0, 0, 0, None))(keys, ego, peds, params)
        return ego, peds, key

    def drift_init(state: EnvState, key: jax.Array, params: Params) -> tuple:
        return state.ego, state.pedestrians

    def drift_stage(carry: tuple, t: jax.Array, params: Params) -> tuple:
        return vmap(drift, (0, 0, None, None))(*carry, params, static)

    def grid_init(state: EnvState, key: jax.Array, params: Params) -> tuple:
        grid = jnp.zeros((num_envs, *static.grid_shape), jnp.float32)
        return state.ego, state.pedestrians, grid

    def grid_stage(carry: tuple, t: jax.Array, params: Params) -> tuple:
        ego, peds, _ = carry
        ego, peds = vmap(drift, (0, 0, None, None))(ego, peds, params, static)
        grid = vmap(rasterize_grid, (0, 0, None, None))(ego, peds, params, static)
        return ego, peds, grid

    def ttc_init(state: EnvState, key: jax.Array, params: Params) -> tuple:
        return state.ego, state.pedestrians, jnp.full((num_envs,), jnp.inf, jnp.float32)

    def ttc_stage(carry: tuple, t: jax.Array, params: Params) -> tuple:
        ego, peds, low = carry
        ego, peds = vmap(drift, (0, 0, None, None))(ego, peds, params, static)
        ttc = vmap(time_to_collision, (0, 0, None, None))(ego, peds, params, static)
        return ego, peds, jnp.minimum(low, ttc)

    def reward_init(state: EnvState, key: jax.Array, params: Params) -> tuple:
        ttc = vmap(time_to_collision, (0, 0, None, None))(
            state.ego, state.pedestrians, params, static
        )
        return state.ego, state.pedestrians, ttc, jnp.zeros((num_envs,), jnp.float32)

    def one_env_reward(
        ego: EgoState, peds: PedestrianState, ttc: jax.Array, params: Params
    ) -> jax.Array:
        return compute_reward(classify_hits(ego, peds, params)[0], ttc, ego.v, params)

    def reward_stage(carry: tuple, t: jax.Array, params: Params) -> tuple:
        ego, peds, ttc, total = carry
        ego, peds = vmap(drift, (0, 0, None, None))(ego, peds, params, static)
        r = vmap(one_env_reward, (0, 0, 0, None))(ego, peds, ttc, params)
        # The TTC input counts down to 0, then restarts at the horizon (inf stays inf).
        ttc = jnp.where(ttc > 0.0, ttc - static.ttc_step, static.ttc_horizon)
        return ego, peds, ttc.astype(jnp.float32), total + r

    stages = [
        Stage("ego", "action → setpoint → PID → plant (ego_step)", ego_init, ego_stage),
        Stage(
            "pedestrians",
            "step_pedestrians + despawn_mask + respawn_pedestrians (drawn where one is gone)",
            peds_init,
            peds_stage,
        ),
        Stage("grid", "rasterize_grid → (45, 30, 4) float32, on the drift", grid_init, grid_stage),
        Stage("TTC", "time_to_collision, on the drift", ttc_init, ttc_stage),
        Stage("reward", "collision + reward, on the drift", reward_init, reward_stage),
        Stage(
            "drift", "the input driver alone (inside grid, TTC, reward)", drift_init, drift_stage
        ),
    ]
    return {s.name: s for s in stages}


def make_program(stage: Stage, num_steps: int) -> Callable[[Any, Params], Any]:
    """``(carry, params) -> carry``: ``num_steps`` steps of ``stage`` in one ``lax.scan``."""

    def program(carry: Any, params: Params) -> Any:
        def body(c: Any, t: jax.Array) -> tuple[Any, None]:
            return stage.step(c, t, params), None

        carry, _ = jax.lax.scan(body, carry, jnp.arange(num_steps, dtype=jnp.int32))
        return carry

    return program


def _fresh(tree: Any) -> Any:
    """A copy of every leaf in new buffers (the programs donate their carry)."""
    return jax.tree.map(lambda x: x.copy(), tree)


def _row(
    name: str,
    what: str,
    num_envs: int,
    num_steps: int,
    timing: dict[str, Any],
) -> dict[str, Any]:
    """A stage's row from its timing (compile and ``time_calls`` figures)."""
    env_steps = num_envs * num_steps
    steps_per_s = env_steps / timing["run_s"]
    return {
        **timing,
        "stage": name,
        "what": what,
        "batch_size": num_envs,
        "steps": num_steps,
        "env_steps_per_call": env_steps,
        "env_steps_per_s": steps_per_s,
        "ns_per_env_step": 1e9 / steps_per_s,
    }


def _finite(tree: Any) -> bool:
    """Every float leaf is finite or +inf (TTC may be inf), none NaN."""
    leaves = [x for x in jax.tree.leaves(tree) if jnp.issubdtype(x.dtype, jnp.floating)]
    return all(not bool(jnp.any(jnp.isnan(x))) for x in leaves)


def bench_batch(
    env: drqn_jax.UrbanPedestrians,
    params: Params,
    num_envs: int,
    num_steps: int,
    repeats: int,
    warmup_steps: int,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """All stage rows for ``num_envs`` envs, the full step first; shares filled in."""
    key = jax.random.key(seed)
    key, init_key = jax.random.split(key)
    # the full step: compile, bring the states to life, time
    timing, carry, _ = time_rollout(
        env, params, num_envs, num_steps, repeats, init_key, warmup_steps=warmup_steps
    )
    what = "env.step with auto-reset, random actions (benchmarks/env_throughput.py)"
    rows = [_row(FULL, what, num_envs, num_steps, timing)]
    _, state, _ = carry
    del carry
    _progress(rows[-1])

    for name, stage in make_stages(env, num_envs).items():
        key, stage_key = jax.random.split(key)
        c = jax.block_until_ready(_fresh(jax.jit(stage.init)(state, stage_key, params)))
        program = jax.jit(make_program(stage, num_steps), donate_argnums=0)
        compiled, lower_s, xla_s = compile_timed(program, c, params)
        c, timing = time_calls(lambda c, f=compiled: f(c, params), c, repeats)
        timing = {
            "lower_s": lower_s,
            "xla_compile_s": xla_s,
            "compile_s": lower_s + xla_s,
            **timing,
        }
        rows.append(_row(name, stage.what, num_envs, num_steps, timing))
        rows[-1]["output_finite"] = _finite(c)
        del c, compiled
        _progress(rows[-1])

    full_ns = rows[0]["ns_per_env_step"]
    for row in rows:
        row["share_of_full_step"] = row["ns_per_env_step"] / full_ns
    order = {n: i for i, n in enumerate(STAGE_NAMES)}
    return sorted(rows, key=lambda r: order[r["stage"]])


def _progress(row: dict[str, Any]) -> None:
    print(
        f"[N = {row['batch_size']}, {row['stage']}: compile {row['compile_s']:.2f} s, run "
        f"{row['run_s']:.4f} s, {row['env_steps_per_s']:,.0f} env steps/s, cores used per "
        f"timed call {', '.join(f'{c:.2f}' for c in row['cores_used_per_call'])}]",
        file=sys.stderr,
        flush=True,
    )


def summary(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per N: the sum of the step stages' times against the full step's."""
    out = []
    for n in sorted({r["batch_size"] for r in rows}):
        at_n = {r["stage"]: r for r in rows if r["batch_size"] == n}
        stage_sum = sum(at_n[s]["ns_per_env_step"] for s in STEP_STAGES)
        biggest = max(STEP_STAGES, key=lambda s: at_n[s]["ns_per_env_step"])
        out.append(
            {
                "batch_size": n,
                "full_ns_per_env_step": at_n[FULL]["ns_per_env_step"],
                "sum_of_stages_ns_per_env_step": stage_sum,
                "sum_of_stages_share": stage_sum / at_n[FULL]["ns_per_env_step"],
                "largest_stage": biggest,
                "largest_stage_share": at_n[biggest]["share_of_full_step"],
            }
        )
    return out


COLUMNS = {
    "batch_size": "N envs",
    "stage": "stage",
    "compile_s": "compile s",
    "run_s": "run s (median)",
    "env_steps_per_s": "env steps/s",
    "ns_per_env_step": "ns per env-step",
    "share_of_full_step": "share of full step",
}


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = base_parser("stages", __doc__)
    parser.add_argument(
        "--batch-sizes",
        type=int,
        nargs="+",
        default=list(DEFAULT_BATCH_SIZES),
        metavar="N",
        help="numbers of envs (default: %(default)s)",
    )
    parser.add_argument("--steps", type=int, default=50, metavar="T", help="scan length (50)")
    parser.add_argument(
        "--warmup-steps",
        type=int,
        default=50,
        metavar="W",
        help="random full steps from reset before timing, for realistic states (50)",
    )
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument(
        "--quick", action="store_true", help="N = 64, T = 10, 2 repeats: a smoke check"
    )
    args = parser.parse_args(argv)
    if args.quick:
        args.batch_sizes, args.steps, args.repeats = list(QUICK_BATCH_SIZES), QUICK_STEPS, 2
        args.warmup_steps = min(args.warmup_steps, QUICK_STEPS)
    if min(args.steps, args.repeats, *args.batch_sizes) < 1 or args.warmup_steps < 0:
        parser.error("--batch-sizes, --steps, --repeats must be >= 1, --warmup-steps >= 0")
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Run the benchmark; print (and with ``--out`` write) the report; return the result."""
    args = parse_args(argv)
    env, params = drqn_jax.make(ENV_ID)
    rows = []
    for n in args.batch_sizes:
        rows += bench_batch(env, params, n, args.steps, args.repeats, args.warmup_steps, args.seed)
    summ = summary(rows)

    lines = [
        f"`{ENV_ID}`: each stage of the env step alone, `lax.scan` of {args.steps} steps of "
        f"`jax.vmap(stage)` on N envs (states after {args.warmup_steps} random full steps "
        f"from reset); run s = median of {args.repeats} timed calls after 1 warm-up; compile "
        "s = lower + XLA compile; share = the stage's time per env-step ÷ the full step's at "
        "the same N. Grid, TTC and reward run on a drifting state; the drift row is that "
        "driver alone (included in those three rows, not subtracted)."
        + (" QUICK: a smoke check, not a measurement." if args.quick else ""),
        "",
        *markdown_table(rows, COLUMNS),
        "",
    ]
    for s in summ:
        lines.append(
            f"- N = {s['batch_size']}: ego + pedestrians + grid + TTC + reward alone take "
            f"{s['sum_of_stages_ns_per_env_step']:,.0f} ns per env-step, "
            f"{100 * s['sum_of_stages_share']:.0f}% of the full step's "
            f"{s['full_ns_per_env_step']:,.0f} ns; largest: {s['largest_stage']} "
            f"({100 * s['largest_stage_share']:.0f}%)"
        )
    result = {
        "env_id": ENV_ID,
        "config": {
            "quick": args.quick,
            "batch_sizes": args.batch_sizes,
            "steps": args.steps,
            "repeats": args.repeats,
            "warmup_steps": args.warmup_steps,
            "seed": args.seed,
            "stat": "median",
        },
        "rows": rows,
        "summary": summ,
    }
    title = f"Env step stages vs number of envs ({ENV_ID})"
    return report("stages", title, result, lines, args.out, argv)


if __name__ == "__main__":
    main()
