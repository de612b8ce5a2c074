"""The learner on benchmarks nobody here wrote: gymnax CartPole-v1 and MemoryChain-bsuite.

Before the learner is tuned on our env it must reproduce published behaviour
on outside environments (gymnax 1.0.1, installed with ``--no-deps``; see the
README):

* ``cartpole-dqn``: the memoryless ``dqn`` variant on ``CartPole-v1``, with
  PureJaxRL's DQN recipe as far as ours has the knobs (:func:`cartpole_config`)
  and its budget of about 5·10⁵ env steps (2000 episodes). Target: mean
  greedy return ≥ 475 (of 500), every seed.
* ``cartpole-ppo``: recurrent PPO (:mod:`drqn_jax.learners.ppo`) on ``CartPole-v1``
  with PureJaxRL's ppo_rnn recipe and its budget (5·10⁵ env steps) in
  episodes (:func:`ppo_config`). Target: mean greedy return ≥ 475, every seed.
* ``cartpole-pqn``: recurrent PQN (:mod:`drqn_jax.learners.pqn`) on
  ``CartPole-v1`` with purejaxql's ``pqn_rnn_cartpole.yaml`` and its budget
  (5·10⁵ env steps; :func:`pqn_config`). Target: mean greedy return ≥ 475.
* ``memory100-pqn``: recurrent PQN on MemoryChain with purejaxql's
  ``pqn_rnn_memory_chain.yaml`` (memory length 100, 10⁵ env steps;
  :func:`pqn_memory_config`). Target: ≥ 90 % success. ``memory100-pqn-wide``:
  the same at purejaxql's width (256); ``memory100-pqn-gru``: and with GRUs
  (``network.cell = "gru"``), purejaxql's cell; ``memory30-pqn``: with memory
  length 30.
* ``memory-drqn`` / ``memory-dqn``: bsuite's MemoryChain (gymnax defaults:
  memory length 5, one context bit): the first observation shows a bit that
  the last action must repeat (+1, else −1). The DRQN sees whole episodes in
  its 8-step windows. Target: DRQN ≥ 90 % success, the memoryless DQN near
  chance (50 %).
* ``memory12-drqn`` / ``memory12-drqn-stored``: memory length 12, longer than
  the 8-step windows: a DRQN whose replayed windows start from zeros cannot
  learn it; with R2D2's stored state (``train.stored_state = 1``) it can.

Each recipe trains ``--seeds`` seeds in one ``vmap`` and plays
``--episodes`` greedy episodes per seed on a key of its own. Usage::

    python -m benchmarks.gymnax_validation [--seeds 3] [--episodes 100] [--out DIR]
"""

import time
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.harness import base_parser, markdown_table, report
from drqn_jax.evaluation import episode_keys
from drqn_jax.learners import Hyperparams, TrainConfig, make_train
from drqn_jax.learners.task import greedy_returns
from drqn_jax.networks import NetworkConfig

#: Small dense networks for flat observations: MLP torso 64 → core 64 → FC 64, their
#: scans one step per loop iteration (on the CPU PPO's updates ran faster so, and every
#: recipe compiles faster; the bits are those of any other ``scan_unroll``).
SMALL = {"recurrent": 64, "hidden": 64, "mlp": (64,), "scan_unroll": 1}


def cartpole_config(num_episodes: int = 2000, snapshots: int = 19, **hyper: Any) -> TrainConfig:
    """The memoryless DQN on gymnax CartPole-v1: PureJaxRL's DQN recipe where ours
    has the knob (10 envs, about 128 transitions per minibatch, γ 0.99, target
    copy every 500 updates, one update per vector step, ε 1 → 0.05) and five of
    the project's options, chosen on seeds 0–2 among the variants that
    benchmarks/RESULTS.md lists: ε falls over the first 30 % of the episodes,
    R2D2's value rescaling and 3-step targets (windows of 3 that may start at any
    step), learning rate 5e-4 (PureJaxRL: 2.5e-4), and the agent chosen among
    ``snapshots`` + 1 candidates on 10 greedy validation episodes."""
    hp = dict(
        learning_rate=5e-4,
        gamma=0.99,
        epsilon_start=1.0,
        epsilon_end=0.05,
        epsilon_fraction=0.3,
        explore_bias_fraction=0.0,
        target_period=500,
        learning_starts=20,
        value_rescale=1,
        window_start="anywhere",
    )
    return TrainConfig(
        env_id="gymnax:CartPole-v1",
        network=NetworkConfig(kind="dqn", **SMALL),
        num_envs=10,
        num_episodes=num_episodes,
        replay_episodes=100,
        batch_size=43,
        window=3,
        n_step=3,
        chunk_iterations=500,
        snapshots=snapshots,
        validation_episodes=10,
        hyperparams=Hyperparams(**{**hp, **hyper}),
    )


def memory_config(
    kind: str, num_episodes: int = 3000, memory_length: int = 5, stored_state: int = 0, **hyper: Any
) -> TrainConfig:
    """A DRQN (``kind = "drqn"``) or memoryless DQN on gymnax MemoryChain-bsuite with
    its memory length (episodes of ``memory_length`` + 1 steps), the DRQN's
    replayed windows starting from zeros or from the stored state (R2D2's)."""
    hp = dict(
        learning_rate=1e-3,
        gamma=0.99,
        epsilon_start=1.0,
        epsilon_end=0.05,
        explore_bias_fraction=0.0,
        target_period=100,
        learning_starts=20,
    )
    return TrainConfig(
        env_id="gymnax:MemoryChain-bsuite",
        env_overrides=(("max_steps", memory_length + 1), ("memory_length", memory_length)),
        network=NetworkConfig(kind=kind, **SMALL),
        num_envs=10,
        num_episodes=num_episodes,
        replay_episodes=500,
        batch_size=32,
        window=8,
        chunk_iterations=500,
        stored_state=stored_state,
        hyperparams=Hyperparams(**{**hp, **hyper}),
    )


def ppo_config(num_env_steps: int = 976 * 4 * 128, num_episodes: int = 10_000) -> TrainConfig:
    """Recurrent PPO (``algorithm = "ppo"``) on gymnax CartPole-v1 with PureJaxRL's
    ppo_rnn recipe (4 envs × 128 steps, 4 epochs of 4 minibatches, lr 2.5e-4
    falling linearly to 0, Adam ε 1e-5, γ 0.99, λ 0.95, clip 0.2, entropy 0.01,
    value 0.5, grad norm 0.5) and its budget: 976 updates = 499,712 env steps
    (``train.num_env_steps``; ``num_episodes`` only sizes the metrics, a
    bound it does not reach: seeds 0–2 end 2,544–6,574 episodes), over which
    the rate falls exactly as PureJaxRL's does. Our core is two LSTMs of 64
    after a 64-wide MLP torso (theirs one GRU of 128 between dense layers)."""
    hp = dict(
        learning_rate=2.5e-4,
        learning_rate_end=0.0,
        adam_eps=1e-5,
        gamma=0.99,
        gae_lambda=0.95,
        clip_eps=0.2,
        ent_coef=0.01,
        vf_coef=0.5,
        max_grad_norm=0.5,
    )
    return TrainConfig(
        env_id="gymnax:CartPole-v1",
        network=NetworkConfig(kind="drqn", **SMALL),
        algorithm="ppo",
        num_envs=4,
        num_episodes=num_episodes,
        num_env_steps=num_env_steps,
        rollout_steps=128,
        update_epochs=4,
        num_minibatches=4,
        chunk_iterations=100,
        hyperparams=Hyperparams(**hp),
    )


def pqn_config(num_env_steps: int = 500_000, num_episodes: int = 20_000) -> TrainConfig:
    """Recurrent PQN (``algorithm = "pqn"``) on gymnax CartPole-v1 with purejaxql's
    ``pqn_rnn_cartpole.yaml`` where the learner has the setting: 32 envs × 64
    steps, 4 epochs of 16 minibatches, RAdam at lr 1e-4 falling linearly to 0,
    γ 0.99, λ 0.95, rewards × 0.1, grad norm 10, LayerNorm, ε from 1 to 0.2 over
    the first 20 % of the 500,000 env steps. Not theirs: no memory window; our
    core is two LSTMs of 64 after a 64-wide MLP torso (theirs a GRU of 256
    after two dense layers of 256)."""
    hp = dict(
        learning_rate=1e-4,
        learning_rate_end=0.0,
        gamma=0.99,
        q_lambda=0.95,
        max_grad_norm=10.0,
        epsilon_start=1.0,
        epsilon_end=0.2,
        epsilon_fraction=0.2,
        reward_scale=0.1,
    )
    return TrainConfig(
        env_id="gymnax:CartPole-v1",
        network=NetworkConfig(kind="drqn", layer_norm=True, **SMALL),
        algorithm="pqn",
        optimizer="radam",
        num_envs=32,
        num_episodes=num_episodes,
        num_env_steps=num_env_steps,
        rollout_steps=64,
        update_epochs=4,
        num_minibatches=16,
        chunk_iterations=50,
        hyperparams=Hyperparams(**hp),
    )


def pqn_memory_config(
    memory_length: int = 100,
    num_env_steps: int = 100_000,
    width: int | None = None,
    cell: str = "lstm",
) -> TrainConfig:
    """Recurrent PQN on gymnax MemoryChain-bsuite with purejaxql's
    ``pqn_rnn_memory_chain.yaml``: memory length 100 (episodes of 101 steps),
    10⁵ env steps, 32 envs × 128 steps, 4 epochs of 16 minibatches, RAdam at a
    constant lr 1e-3, γ 0.99, λ 0.95, grad norm 10, LayerNorm, ε from 1 to 0.01
    over the first 10 %. Not theirs: no memory window (each minibatch unrolls
    from the acting state at its rollout's start), LSTMs for their GRU unless
    ``cell = "gru"``, two recurrent layers and an FC layer for their one GRU, and
    our narrower core unless ``width`` (theirs: 256, two dense layers and the
    recurrent layer of that width)."""
    hp = dict(
        learning_rate=1e-3,
        gamma=0.99,
        q_lambda=0.95,
        max_grad_norm=10.0,
        epsilon_start=1.0,
        epsilon_end=0.01,
        epsilon_fraction=0.1,
        explore_bias_fraction=0.0,
    )
    core = dict(SMALL)
    if width is not None:
        core.update(recurrent=width, hidden=width, mlp=(width,) * 2)
    return TrainConfig(
        env_id="gymnax:MemoryChain-bsuite",
        env_overrides=(("max_steps", memory_length + 1), ("memory_length", memory_length)),
        network=NetworkConfig(kind="drqn", layer_norm=True, cell=cell, **core),
        algorithm="pqn",
        optimizer="radam",
        num_envs=32,
        num_episodes=num_env_steps // (memory_length + 1) + 64,
        num_env_steps=num_env_steps,
        rollout_steps=128,
        update_epochs=4,
        num_minibatches=16,
        chunk_iterations=50,
        hyperparams=Hyperparams(**hp),
    )


#: name -> (config, success threshold on the mean greedy return, target text).
RECIPES = {
    "cartpole-dqn": (cartpole_config, 475.0, "mean greedy return ≥ 475"),
    "cartpole-ppo": (ppo_config, 475.0, "mean greedy return ≥ 475"),
    "cartpole-pqn": (pqn_config, 475.0, "mean greedy return ≥ 475"),
    "memory100-pqn": (pqn_memory_config, None, "success ≥ 90 % (purejaxql's memory length 100)"),
    "memory100-pqn-wide": (
        lambda: pqn_memory_config(width=256),
        None,
        "success ≥ 90 % (memory length 100, purejaxql's width 256)",
    ),
    "memory100-pqn-gru": (
        lambda: pqn_memory_config(width=256, cell="gru"),
        None,
        "success ≥ 90 % (memory length 100, purejaxql's width 256 and GRU)",
    ),
    "memory30-pqn": (
        lambda: pqn_memory_config(memory_length=30),
        None,
        "success ≥ 90 % (memory length 30; episodes fit in a 128-step rollout)",
    ),
    "memory-drqn": (lambda: memory_config("drqn"), None, "success ≥ 90 %"),
    "memory-dqn": (lambda: memory_config("dqn"), None, "success near 50 % (no memory)"),
    "memory12-drqn": (
        lambda: memory_config("drqn", memory_length=12),
        None,
        "near 50 %: 8-step windows from zeros cannot span 13 steps",
    ),
    "memory12-drqn-stored": (
        lambda: memory_config("drqn", memory_length=12, stored_state=1),
        None,
        "success ≥ 90 % (windows start from the stored state)",
    ),
}


def run_recipe(config: TrainConfig, seeds: int, episodes: int, seed0: int = 0) -> dict[str, Any]:
    """Train ``seeds`` seeds of ``config`` (DQN/DRQN or PPO) at once, then play
    ``episodes`` greedy episodes each: per seed the mean greedy return and the
    success rate (return > 0), the env steps of its training episodes, and the
    wall time (compile included)."""
    trainer = make_train(config)
    keys = jax.vmap(jax.random.key)(jnp.arange(seed0, seed0 + seeds))
    start = time.perf_counter()
    params, metrics = jax.block_until_ready(jax.jit(jax.vmap(trainer.train))(keys))
    train_s = time.perf_counter() - start
    steps = [int(n) for n in np.asarray(metrics["length"]).sum(axis=1)]
    eval_keys = jax.vmap(lambda k: jax.random.fold_in(k, 7))(keys)

    def play(params, key):
        return greedy_returns(trainer.task, trainer.network, params, episode_keys(key, episodes))

    returns = np.asarray(jax.jit(jax.vmap(play))(params, eval_keys))
    return {
        "mean_return": [float(r) for r in returns.mean(axis=1)],
        "success": [float(s) for s in (returns > 0).mean(axis=1)],
        "env_steps": steps,
        "train_s": train_s,
    }


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("gymnax_validation", __doc__)
    parser.add_argument("--seeds", type=int, default=3, help="seeds per recipe (default 3)")
    parser.add_argument(
        "--episodes", type=int, default=100, help="greedy episodes per seed (default 100)"
    )
    parser.add_argument("--first-seed", type=int, default=0, help="seeds first-seed, … (default 0)")
    parser.add_argument(
        "--recipes", nargs="+", default=list(RECIPES), choices=list(RECIPES), help="which to run"
    )
    args = parser.parse_args(argv)
    rows = []
    for name in args.recipes:
        make_config, threshold, target = RECIPES[name]
        out = run_recipe(make_config(), args.seeds, args.episodes, args.first_seed)
        passed = all(r >= threshold for r in out["mean_return"]) if threshold is not None else None
        rows.append(
            {
                "recipe": name,
                "target": target,
                "mean_return": " / ".join(f"{r:.1f}" for r in out["mean_return"]),
                "success": " / ".join(f"{100 * s:.0f} %" for s in out["success"]),
                "env_steps": " / ".join(f"{n:,}" for n in out["env_steps"]),
                "train_s": out["train_s"],
                "met": {True: "yes", False: "no", None: "see success"}[passed],
                **{f"raw_{k}": v for k, v in out.items()},
            }
        )
    columns = {
        "recipe": "recipe",
        "target": "target",
        "mean_return": "greedy return per seed",
        "success": "success (return > 0) per seed",
        "env_steps": "env steps of the training episodes, per seed",
        "train_s": "train wall s (all seeds)",
        "met": "target met",
    }
    lines = markdown_table(rows, columns)
    seeds = f"seeds {args.first_seed}–{args.first_seed + args.seeds - 1}"
    lines += ["", f"{seeds} trained in one vmap; {args.episodes} greedy episodes each."]
    title = "The learner on gymnax"
    return report("gymnax_validation", title, {"rows": rows}, lines, args.out, argv)


if __name__ == "__main__":
    main()
