"""Make a training-curves figure from runs' ``metrics.csv`` files (docs/notebook/).

The paper's "Training performance" figure (average reward and steps per
episode against training episode) for any set of runs: a ``drqn-jax train``
run directory, or the ``metrics/run-NNNN.csv`` files of a sweep or a study.
Runs given together under one label are pooled (mean and min–max over them)::

    python docs/training_curves.py --out docs/figures/paper-seed0.png \\
        "paper, seed 0=runs/paper-seed0/metrics.csv"
    python docs/training_curves.py --out docs/figures/default.png \\
        "default=runs/study-default/default/metrics/run-0000.csv,runs/study-default/default/metrics/run-0001.csv"

Needs matplotlib (``pip install -e ".[plots]"``). ``drqn-jax study`` draws the
same figure (``OUT/curves.png``) for its own configs.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from drqn_jax.experiments.curves import load_curves, plot_curves


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "curves",
        nargs="+",
        metavar="LABEL=CSV[,CSV…]",
        help="a label and the metrics.csv files (or run directories) pooled under it",
    )
    parser.add_argument("--out", required=True, help="the PNG to write")
    parser.add_argument("--smooth", type=int, default=10, help="running mean (episodes)")
    args = parser.parse_args(argv)
    curves = {}
    for spec in args.curves:
        label, sep, files = spec.partition("=")
        if not sep or not files:
            parser.error(f"{spec!r}: expected LABEL=CSV[,CSV…]")
        paths = [Path(f) for f in files.split(",")]
        paths = [p / "metrics.csv" if p.is_dir() else p for p in paths]
        curves[label] = load_curves(paths, args.smooth)
    plot_curves(curves, args.out, args.smooth)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
