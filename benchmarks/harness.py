"""What every benchmark of the suite shares: timing, the machine block, reports.

A benchmark module ``benchmarks/NAME.py`` defines ``main(argv) -> dict`` and
runs as ``python -m benchmarks.NAME`` or ``drqn-jax bench NAME``. It times
with :func:`compile_timed` (compile apart from run) and :func:`time_calls`
(one warm-up call, then the MEDIAN of ``repeats`` timed calls) and ends with
:func:`report`, which prints a Markdown section (title, table, machine block,
the command) and, with ``--out DIR``, writes ``DIR/NAME.json`` and
``DIR/NAME.md``.
"""

import argparse
import json
import os
import shlex
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax

from drqn_jax.experiments.machine import machine_info, machine_lines


def base_parser(name: str, doc: str | None) -> argparse.ArgumentParser:
    """An argument parser with the suite's common options: ``--repeats``, ``--out``."""
    parser = argparse.ArgumentParser(
        prog=f"python -m benchmarks.{name}",
        description=(doc or "").split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--repeats", type=int, default=5, help="timed calls after one warm-up (default 5)"
    )
    parser.add_argument(
        "--out", metavar="DIR", help=f"write DIR/{name}.json and DIR/{name}.md as well"
    )
    return parser


def compile_timed(jitted: Any, *args: Any) -> tuple[jax.stages.Compiled, float, float]:
    """Lower and compile; the executable, lower seconds and XLA compile seconds."""
    t0 = time.perf_counter()
    lowered = jitted.lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    return compiled, t1 - t0, time.perf_counter() - t1


def time_calls(
    call: Callable[[Any], Any], carry: Any, repeats: int, stat: str = "median"
) -> tuple[Any, dict[str, Any]]:
    """One warm-up call, then ``repeats`` timed calls, each continuing from the last
    result (``carry = call(carry)``). ``run_s`` is the median (or ``stat = "best"``)."""
    if repeats < 1:
        raise ValueError(f"--repeats = {repeats}: must be >= 1")
    t = time.perf_counter()
    carry = jax.block_until_ready(call(carry))
    warmup_s = time.perf_counter() - t
    run_times, cores = [], []
    for _ in range(repeats):
        cpu, t = time.process_time(), time.perf_counter()
        carry = jax.block_until_ready(call(carry))
        run_times.append(time.perf_counter() - t)
        # CPU seconds per wall second: about the cores this process got.
        cores.append((time.process_time() - cpu) / run_times[-1])
    run_s = min(run_times) if stat == "best" else statistics.median(run_times)
    return carry, {
        "warmup_s": warmup_s,
        "run_times_s": run_times,
        "run_s": run_s,
        "stat": stat,
        "cores_used_per_call": cores,
        "loadavg_after": os.getloadavg()[0],
    }


def write_json(path: str | Path, result: dict[str, Any]) -> None:
    """``result`` as indented JSON at ``path`` (non-JSON values as ``str``), and say so."""
    Path(path).write_text(json.dumps(result, indent=2, default=str) + "\n", encoding="utf-8")
    print(f"wrote {path}", file=sys.stderr)


def _cell(value: Any) -> str:
    if isinstance(value, float):
        if value != value:  # NaN
            return "–"
        if abs(value) >= 1e5:
            return f"{value:,.0f}"
        return f"{value:.3g}" if abs(value) < 100 else f"{value:,.1f}"
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{value:,}"
    return str(value)


def markdown_table(rows: Sequence[dict[str, Any]], columns: dict[str, str]) -> list[str]:
    """A Markdown table: one line per row, ``columns`` maps row keys to headers."""
    lines = ["| " + " | ".join(columns.values()) + " |", "|" + "---|" * len(columns)]
    return lines + ["| " + " | ".join(_cell(r.get(k, "")) for k in columns) + " |" for r in rows]


def report(
    name: str,
    title: str,
    result: dict[str, Any],
    lines: Sequence[str],
    out: str | Path | None,
    argv: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Print (and with ``out`` write) a benchmark's Markdown and JSON; returns ``result``
    with the machine block and the command added."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command = " ".join(["python -m", f"benchmarks.{name}", *map(shlex.quote, argv)])
    result = {"benchmark": name, "command": command, "machine": machine_info(), **result}
    md = [f"## {title}", "", *lines, "", f"Command: `{command}`", ""]
    md += [*machine_lines(result["machine"]), ""]
    print("\n".join(md))
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / f"{name}.json", result)
        (out / f"{name}.md").write_text("\n".join(md), encoding="utf-8")
        print(f"wrote {out / f'{name}.md'}", file=sys.stderr)
    return result
