"""Which batch sizes round the shipped network's matrix products differently.

XLA:CPU runs row-major matrix products through YNNPACK, which picks its kernel by
the number of rows m: below some m (by shape) a row's result differs in the last
bits from the same row in a big batch. An evaluation batch therefore runs at least
``drqn_jax.evaluation.MIN_BATCH`` episodes (padding included), so that episode i
has the same bits whatever the episodes beside it. This script measures, for each
product of the shipped agent's network (``(k, n)``: the input width and output
width of each matrix), every m in ``1..--max-rows`` whose rows differ from the same
rows computed among ``--reference`` rows, and says whether ``MIN_BATCH`` is above
them all on this machine.

    python -m benchmarks.matmul_rows [--max-rows 160] [--out DIR]
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import drqn_jax  # noqa: F401  (its XLA flags first)
from benchmarks.harness import base_parser, markdown_table, report
from drqn_jax.agents.shipped import shipped_agent_dir
from drqn_jax.evaluation import MIN_BATCH

__all__ = ["differing_rows", "network_products"]


def network_products(agent: str = "headline") -> dict[str, tuple[int, int]]:
    """The (k, n) of every matrix product of a shipped agent's forward pass: a conv
    kernel (kh, kw, C, F) multiplies patches (kh·kw·C, F); a GRU's (n_in + H, 3H)
    weights multiply the input (n_in, 3H) and the state (H, 3H); a dense (k, n). A GRU
    with extra inputs (speed, last action) multiplies them in a product of their own;
    here they count in the input's (the same n, a k a few wider)."""
    weights = np.load(shipped_agent_dir(agent) / "agent.npz")
    shapes: dict[str, tuple[int, int]] = {}
    for name in sorted(weights.files):
        w = weights[name]
        if not name.endswith("_w") or w.ndim < 2:
            continue
        layer = name[:-2]
        if w.ndim == 4:
            shapes[layer] = (int(np.prod(w.shape[:3])), int(w.shape[3]))
        elif f"{layer}_b_hn" in weights.files:
            hidden = int(weights[f"{layer}_b_hn"].shape[0])
            shapes[f"{layer} input"] = (int(w.shape[0]) - hidden, int(w.shape[1]))
            shapes[f"{layer} state"] = (hidden, int(w.shape[1]))
        else:
            shapes[layer] = (int(w.shape[0]), int(w.shape[1]))
    return shapes


def differing_rows(
    k: int, n: int, rows: Sequence[int], reference: int = 1024, seed: int = 0
) -> list[int]:
    """Every m of ``rows`` for which ``(x[:m] @ w)`` differs from ``(x @ w)[:m]``, x
    (reference, k) and w (k, n) standard normal float32."""
    rng = np.random.default_rng(seed)
    w = jnp.asarray(rng.standard_normal((k, n)), jnp.float32)
    x = jnp.asarray(rng.standard_normal((reference, k)), jnp.float32)
    product = jax.jit(lambda a, b: a @ b)
    every = np.asarray(product(x, w))
    return [m for m in rows if not np.array_equal(np.asarray(product(x[:m], w)), every[:m])]


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = base_parser("matmul_rows", __doc__)
    parser.add_argument("--max-rows", type=int, default=160, help="largest m tried (160)")
    parser.add_argument("--reference", type=int, default=1024, help="rows of the big batch")
    args = parser.parse_args(argv)
    rows = []
    for layer, (k, n) in network_products().items():
        differ = differing_rows(k, n, range(1, args.max_rows + 1), args.reference)
        rows.append(
            {
                "product": layer,
                "k": k,
                "n": n,
                "differing": len(differ),
                "largest_differing": max(differ, default=0),
            }
        )
    worst = max(r["largest_differing"] for r in rows)
    result = {
        "max_rows": args.max_rows,
        "reference_rows": args.reference,
        "min_batch": MIN_BATCH,
        "largest_differing_rows": worst,
        "min_batch_suffices": worst < MIN_BATCH,
        "products": rows,
    }
    columns = {
        "product": "product",
        "k": "k",
        "n": "n",
        "differing": f"m in 1..{args.max_rows} that differ",
        "largest_differing": "largest such m",
    }
    verdict = "above" if worst < MIN_BATCH else "NOT above"
    lines = [
        *markdown_table(rows, columns),
        "",
        f"MIN_BATCH = {MIN_BATCH} is {verdict} every m that rounds differently here "
        f"(largest {worst}; reference {args.reference} rows).",
    ]
    return report("matmul_rows", "Matrix rows and rounding", result, lines, args.out, argv=argv)


if __name__ == "__main__":
    main()
