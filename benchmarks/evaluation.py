"""Evaluation throughput: whole greedy episodes per second, rule-based agent and DRQN.

Usage::

    python -m benchmarks.evaluation [--episodes 1024] [--repeats 5] [--out DIR]
    drqn-jax bench evaluation …

Times ``drqn_jax.evaluation.run_episodes``, the program behind
``drqn_jax.evaluate`` and ``drqn-jax evaluate`` (SPEC §8): N episodes of
``UrbanPedestrians-v0`` in parallel under one ``jit``, each a ``lax.scan`` of
the episode limit (1000 steps), the agent acting every step. Agents: the
rule-based agent (SPEC §6) and the DRQN (paper Table I network; freshly
initialised weights: the cost of acting does not depend on what was learned).
Compile time apart from run time; the run time is the median of ``--repeats``
calls after a warm-up, each on new episode keys. Reported: episodes/s, agent
steps/s (N × 1000 scanned steps per call, finished episodes included: the scan
runs them masked) and µs per agent step.
"""

from collections.abc import Sequence
from typing import Any

import jax

import drqn_jax
from benchmarks.harness import base_parser, compile_timed, markdown_table, report, time_calls
from drqn_jax.evaluation import episode_keys, run_episodes
from drqn_jax.networks import NetworkConfig, make_network

ENV_ID = "UrbanPedestrians-v0"


def agents(env: drqn_jax.UrbanPedestrians, seed: int) -> dict[str, drqn_jax.Agent]:
    """The rule-based agent and a paper-network DRQN with initial weights."""
    network = make_network(NetworkConfig(grid_shape=env.static.grid_shape))
    params = network.init(jax.random.key(seed))
    return {
        "rule-based": drqn_jax.rule_based_agent(),
        "drqn": drqn_jax.drqn_agent(network, params),
    }


def bench_agent(
    agent: drqn_jax.Agent,
    env: drqn_jax.UrbanPedestrians,
    params: drqn_jax.EnvParams,
    num_episodes: int,
    repeats: int,
    seed: int,
) -> dict[str, Any]:
    """Compile and time ``num_episodes`` parallel episodes of ``agent``; its row."""
    keys = episode_keys(jax.random.key(seed), num_episodes)
    compiled, lower_s, xla_s = compile_timed(
        jax.jit(run_episodes, static_argnames=("env",)), agent, keys, env, params
    )
    offset = [0]

    def call(_: Any) -> Any:
        offset[0] += num_episodes
        return compiled(agent, episode_keys(jax.random.key(seed), num_episodes, offset[0]), params)

    last, timing = time_calls(call, None, repeats)
    steps = num_episodes * env.static.max_steps
    return {
        "agent": agent.name,
        "episodes": num_episodes,
        "scanned_steps_per_call": steps,
        "mean_episode_length": float(last.length.mean()),
        "compile_s": lower_s + xla_s,
        **timing,
        "episodes_per_s": num_episodes / timing["run_s"],
        "agent_steps_per_s": steps / timing["run_s"],
        "us_per_agent_step": 1e6 * timing["run_s"] / steps,
    }


COLUMNS = {
    "agent": "agent",
    "episodes": "episodes per call",
    "compile_s": "compile s",
    "run_s": "run s",
    "episodes_per_s": "episodes/s",
    "agent_steps_per_s": "agent steps/s",
    "us_per_agent_step": "µs per agent step",
    "mean_episode_length": "mean episode length",
}


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("evaluation", __doc__)
    parser.add_argument(
        "--episodes", type=int, default=1024, help="parallel episodes per call (default 1024)"
    )
    parser.add_argument("--agents", nargs="+", choices=("rule-based", "drqn"), default=None)
    parser.add_argument("--seed", type=int, default=0, help="PRNG seed (default 0)")
    parser.add_argument("--quick", action="store_true", help="8 episodes, 2 repeats")
    args = parser.parse_args(argv)
    if args.quick:
        args.episodes, args.repeats = 8, 2
    if args.episodes < 2:
        parser.error(f"--episodes = {args.episodes}: must be >= 2")
    env, params = drqn_jax.make(ENV_ID)
    rows = []
    for name, agent in agents(env, args.seed).items():
        if args.agents is None or name in args.agents:
            rows.append(bench_agent(agent, env, params, args.episodes, args.repeats, args.seed))
    lines = [
        f"{args.episodes} episodes per call (one jitted vmap of {env.static.max_steps}-step "
        f"episode scans); run s = median of {args.repeats} calls after a warm-up.",
        "",
        *markdown_table(rows, COLUMNS),
    ]
    result = {"config": vars(args), "rows": rows}
    return report("evaluation", "Evaluation throughput", result, lines, args.out, argv)


if __name__ == "__main__":
    main()
