"""Where the test suite's time goes: wall, XLA compile, tracing and lowering per test file.

Two halves:

* a pytest plugin that records, for every test, its wall time and what JAX
  reports through ``jax.monitoring`` while it runs (tracing to a jaxpr,
  lowering to MLIR, XLA compiles and their count, persistent-cache hits):
  one TSV line per test in ``$SUITE_PROFILE_DIR/suite-<pid>.tsv`` (one file
  per xdist worker; default ``runs/suite-profile``). Subprocesses a test
  starts are in its wall time only;
* a summary of those files: per test file and in all, slowest first.

Usage, from the repository root (the README's test command with the plugin)::

    SUITE_PROFILE_DIR=runs/suite-profile python -m pytest -q -n 2 --dist loadfile \\
        -p benchmarks.suite_profile
    python -m benchmarks.suite_profile runs/suite-profile --out DIR
"""

from __future__ import annotations

import collections
import os
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import pytest

from benchmarks.harness import base_parser, markdown_table, report

#: The ``jax.monitoring`` duration events summed per test (the last part of each name).
EVENTS = {
    "jaxpr_trace_duration": "trace_s",
    "jaxpr_to_mlir_module_duration": "lower_s",
    "backend_compile_duration": "compile_s",
    "cache_retrieval_time_sec": "cache_hit_s",
}
FIELDS = ("test", "wall_s", *(f for name in EVENTS.values() for f in (name, f"{name}_n")))
DEFAULT_DIR = "runs/suite-profile"

_seconds: collections.Counter[str] = collections.Counter()
_counts: collections.Counter[str] = collections.Counter()


def _listen(event: str, duration: float, **_: Any) -> None:
    name = EVENTS.get(event.rsplit("/", 1)[-1])
    if name is not None:
        _seconds[name] += duration
        _counts[name] += 1


class _Recorder:
    """The plugin proper: one TSV line per test to ``path``."""

    def __init__(self, path: Path) -> None:
        self.path = path

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item: Any, nextitem: Any) -> Any:
        _seconds.clear()
        _counts.clear()
        start = time.perf_counter()
        yield
        values = [f"{time.perf_counter() - start:.3f}"]
        for name in EVENTS.values():
            values += [f"{_seconds[name]:.3f}", str(_counts[name])]
        with open(self.path, "a", encoding="utf-8") as f:
            f.write("\t".join([item.nodeid, *values]) + "\n")


def pytest_configure(config: pytest.Config) -> None:
    """Registers the listener and the recorder in this process (the xdist controller
    runs no test: its file stays empty)."""
    from jax import monitoring

    monitoring.register_event_duration_secs_listener(_listen)
    out = Path(os.environ.get("SUITE_PROFILE_DIR", DEFAULT_DIR))
    out.mkdir(parents=True, exist_ok=True)
    config.pluginmanager.register(_Recorder(out / f"suite-{os.getpid()}.tsv"), "suite-recorder")


def read_rows(paths: Iterable[Path]) -> list[dict[str, Any]]:
    """Every test's row of the plugin's TSV files, with ``worker`` (the file's stem)."""
    rows = []
    for path in paths:
        for line in path.read_text(encoding="utf-8").splitlines():
            cells = line.split("\t")
            row: dict[str, Any] = {"worker": path.stem, "test": cells[0]}
            for field, cell in zip(FIELDS[1:], cells[1:], strict=True):
                row[field] = int(cell) if field.endswith("_n") else float(cell)
            rows.append(row)
    return rows


def by_file(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows summed per test file, slowest first, each with its number of tests."""
    files: dict[str, dict[str, Any]] = {}
    for row in rows:
        name = row["test"].split("::", 1)[0]
        into = files.setdefault(name, {"file": name, "tests": 0, **dict.fromkeys(FIELDS[1:], 0)})
        into["tests"] += 1
        for field in FIELDS[1:]:
            into[field] += row[field]
    return sorted(files.values(), key=lambda r: -r["wall_s"])


def summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Totals, per worker and per file (see :func:`by_file`)."""
    total = {field: sum(r[field] for r in rows) for field in FIELDS[1:]}
    workers = collections.Counter()
    for row in rows:
        workers[row["worker"]] += row["wall_s"]
    return {"tests": len(rows), "total": total, "workers": dict(workers), "files": by_file(rows)}


COLUMNS = {
    "file": "test file",
    "tests": "tests",
    "wall_s": "wall s",
    "compile_s": "XLA compile s",
    "compile_s_n": "compiles",
    "trace_s": "trace s",
    "lower_s": "lower s",
    "cache_hit_s_n": "cache hits",
}


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = base_parser("suite_profile", __doc__)
    parser.add_argument("dir", nargs="?", default=DEFAULT_DIR, help="the plugin's TSV files")
    parser.add_argument("--top", type=int, default=25, help="files listed (default 25)")
    args = parser.parse_args(argv)
    paths = sorted(Path(args.dir).glob("suite-*.tsv"))
    rows = read_rows(p for p in paths if p.stat().st_size)
    if not rows:
        raise SystemExit(f"{args.dir}: no suite-*.tsv with rows; run pytest with the plugin")
    result = summary(rows)
    total = result["total"]
    lines = [
        f"{result['tests']} tests; worker time {total['wall_s']:.0f} s "
        f"({', '.join(f'{w} {s:.0f} s' for w, s in sorted(result['workers'].items()))}), "
        f"of which XLA compile {total['compile_s']:.0f} s ({total['compile_s_n']} compiles), "
        f"tracing {total['trace_s']:.0f} s, lowering {total['lower_s']:.0f} s, "
        f"{total['cache_hit_s_n']} persistent-cache hits; subprocesses count as wall only.",
        "",
        *markdown_table(result["files"][: args.top], COLUMNS),
    ]
    return report("suite_profile", "Where the test suite's time goes", result, lines, args.out)


if __name__ == "__main__":
    main()
