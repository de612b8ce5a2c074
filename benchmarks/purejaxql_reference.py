"""purejaxql's own recurrent PQN on MemoryChain-bsuite: the answer ours is checked against.

``benchmarks/gymnax_validation.py`` trains our recurrent PQN on MemoryChain at
purejaxql's ``pqn_rnn_memory_chain.yaml`` (memory length 100, 10⁵ env steps).
No figure for that setting is published; this script runs purejaxql's own
``pqn_rnn_gymnax.make_train`` on it, unchanged, from a clone of
https://github.com/mttga/purejaxql (``--repo``; run at commit ``47af6d7``), with
``--seeds`` seeds in one ``vmap`` as its ``single_run`` does, and reports its
final greedy test return per seed (its ``TEST_NUM_ENVS`` = 128 envs played for
the env's ``max_steps_in_episode``; success = (return + 1) / 2). Adapters, none
of which touches its learning:

* its imports of ``wandb``, ``hydra`` and ``omegaconf`` are stubbed (only
  ``main`` uses them), and ``jax.tree_map`` (removed from JAX) is ``jax.tree.map``;
* gymnax 1.0's ``step`` returns ``(obs, state, reward, terminated, truncated,
  info)``: the script is given the ``(obs, state, reward, done, info)`` of the
  gymnax it was written for (done = terminated or truncated, as there), without
  1.0's ``final_observation`` in ``info``;
* ``--cell lstm`` swaps its GRU for flax's LSTM of the same width (carry ``[c, h]``
  in one array, so that its code is unchanged): the one difference of network
  family between its learner and ours.

Needs the test extra's flax and optax and ``chex`` (``pip install chex``). Usage::

    python -m benchmarks.purejaxql_reference --repo ../purejaxql [--seeds 3] [--cell lstm]
"""

import functools
import importlib
import sys
import time
import types
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.harness import base_parser, markdown_table, report

#: The commit of purejaxql these figures were taken at.
PUREJAXQL_COMMIT = "47af6d7"


def _gymnax_step_of_its_time() -> None:
    """gymnax 1.0's LogWrapper.step as the 5-tuple purejaxql unpacks."""
    import jax.numpy as jnp
    from gymnax.wrappers import purerl

    six = purerl.LogWrapper.step
    if getattr(six, "five_tuple", False):
        return

    def five(self, key, state, action, params=None):
        obs, state, reward, terminated, truncated, info = six(self, key, state, action, params)
        info = {k: v for k, v in info.items() if k != "final_observation"}
        return obs, state, reward, jnp.logical_or(terminated, truncated), info

    five.five_tuple = True
    purerl.LogWrapper.step = five


def load_purejaxql(repo: Path) -> types.ModuleType:
    """``purejaxql/pqn_rnn_gymnax.py`` of the clone ``repo``, importable here."""
    import jax

    for name in ("wandb", "hydra", "omegaconf"):
        stub = types.ModuleType(name)
        stub.main = lambda **_: lambda f: f
        stub.OmegaConf = None
        sys.modules.setdefault(name, stub)
    jax.tree_map = jax.tree.map
    _gymnax_step_of_its_time()
    sys.path.insert(0, str(repo / "purejaxql"))
    return importlib.import_module("pqn_rnn_gymnax")


def lstm_core() -> Any:
    """A drop-in for purejaxql's ``ScannedRNN`` with flax's LSTM: the carry is ``[c, h]``
    (…, 2H) in one array, reset to zeros where an episode starts, as its GRU's."""
    import flax.linen as nn
    import jax.numpy as jnp

    class ScannedLSTM(nn.Module):
        @functools.partial(
            nn.scan,
            variable_broadcast="params",
            in_axes=0,
            out_axes=0,
            split_rngs={"params": False},
        )
        @nn.compact
        def __call__(self, carry, x):
            ins, resets = x
            width = carry.shape[-1] // 2
            carry = jnp.where(resets[:, None], jnp.zeros_like(carry), carry)
            (c, h), y = nn.OptimizedLSTMCell(width)((carry[..., :width], carry[..., width:]), ins)
            return jnp.concatenate([c, h], axis=-1), y

        @staticmethod
        def initialize_carry(hidden_size, *batch_size):
            return jnp.zeros((*batch_size, 2 * hidden_size))

    return ScannedLSTM


def run(repo: Path, seeds: int, cell: str) -> dict[str, Any]:
    """purejaxql's memory-chain config trained for ``seeds`` seeds in one vmap."""
    import jax
    import yaml

    module = load_purejaxql(repo)
    if cell == "lstm":
        module.ScannedRNN = lstm_core()
    path = repo / "purejaxql" / "config" / "alg" / "pqn_rnn_memory_chain.yaml"
    config = {"NUM_SEEDS": seeds, "SEED": 0, "WANDB_MODE": "disabled"}
    config |= yaml.safe_load(path.read_text())
    for name in ("TOTAL_TIMESTEPS", "TOTAL_TIMESTEPS_DECAY"):
        config[name] = int(float(config[name]))
    start = time.perf_counter()
    keys = jax.random.split(jax.random.PRNGKey(config["SEED"]), seeds)
    out = jax.block_until_ready(jax.jit(jax.vmap(module.make_train(config)))(keys))
    wall = time.perf_counter() - start
    returns = np.asarray(out["metrics"]["test/returned_episode_returns"])  # (seeds, updates)
    return {
        "cell": cell,
        "memory_length": config["ENV_KWARGS"]["memory_length"],
        "env_steps": int(np.asarray(out["metrics"]["env_step"])[0, -1]),
        "updates": int(returns.shape[1]),
        "final_test_return": returns[:, -1].tolist(),
        "final_success": ((returns[:, -1] + 1.0) / 2.0).tolist(),
        "test_return_curve": returns.tolist(),
        "wall_s": wall,
    }


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("purejaxql_reference", __doc__)
    parser.add_argument("--repo", type=Path, required=True, help="a clone of purejaxql")
    parser.add_argument("--seeds", type=int, default=3, help="seeds in one vmap (default 3)")
    parser.add_argument("--cell", choices=("gru", "lstm"), default="gru", help="default gru")
    args = parser.parse_args(argv)
    result = run(args.repo, args.seeds, args.cell)
    row = {
        **result,
        "success": " / ".join(f"{100 * s:.0f} %" for s in result["final_success"]),
        "returns": " / ".join(f"{r:+.3f}" for r in result["final_test_return"]),
    }
    columns = {
        "cell": "core",
        "memory_length": "memory length",
        "env_steps": "env steps per seed",
        "returns": "final greedy test return per seed",
        "success": "success per seed",
        "wall_s": "wall s (all seeds, compile included)",
    }
    lines = [
        f"purejaxql `pqn_rnn_gymnax.py` at {PUREJAXQL_COMMIT} with its "
        "`pqn_rnn_memory_chain.yaml`, seeds in one vmap:",
        "",
        *markdown_table([row], columns),
    ]
    return report("purejaxql_reference", "purejaxql on MemoryChain", result, lines, args.out)


if __name__ == "__main__":
    main()
