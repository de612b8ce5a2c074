"""Where the test suite's time goes: wall, XLA compile, tracing and lowering per test file.

Two halves:

* a pytest plugin that records, for every test, its wall time and what JAX
  reports through ``jax.monitoring`` while it runs (tracing to a jaxpr,
  lowering to MLIR, XLA compiles and their count, persistent-cache hits):
  one TSV line per test in ``$SUITE_PROFILE_DIR/suite-<pid>.tsv`` (one file
  per xdist worker; default ``runs/suite-profile``). Subprocesses a test
  starts are in its wall time only; with it, the memory maps the test left its
  worker holding (``/proc/self/maps`` after minus before: compiled programs hold
  maps, and a worker over Linux's ``vm.max_map_count`` fails to map memory);
  and, per XLA program compiled or loaded from the persistent cache, one line
  in ``compiles-<pid>.tsv``: the test, the program's name, its persistent-cache
  key, ``miss`` or ``hit`` and the compile's seconds;
* a summary of those files: per test file and in all, slowest first, and the
  programs compiled more than once (same cache key: the suite compiled the very
  same program again) or under the most distinct keys (one function compiled
  for many shapes or constants), which say where shared programs would save.

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
from drqn_jax.programs import memory_maps

#: The ``jax.monitoring`` duration events summed per test (the last part of each name).
EVENTS = {
    "jaxpr_trace_duration": "trace_s",
    "jaxpr_to_mlir_module_duration": "lower_s",
    "backend_compile_duration": "compile_s",
    "cache_retrieval_time_sec": "cache_hit_s",
}
FIELDS = (
    "test",
    "wall_s",
    *(f for name in EVENTS.values() for f in (name, f"{name}_n")),
    "maps_added",
)
#: The fields that count (integers); the others are seconds.
COUNTS = (*(f for f in FIELDS if f.endswith("_n")), "maps_added")
DEFAULT_DIR = "runs/suite-profile"

PROGRAM_FIELDS = ("test", "program", "key", "outcome", "compile_s")

_seconds: collections.Counter[str] = collections.Counter()
_counts: collections.Counter[str] = collections.Counter()
#: The running test's programs: [program, key, outcome, compile seconds].
_programs: list[list[Any]] = []
#: A cache miss waits here for its compile's duration.
_pending: list[list[Any]] = []


def _listen(event: str, duration: float, **_: Any) -> None:
    name = EVENTS.get(event.rsplit("/", 1)[-1])
    if name is not None:
        _seconds[name] += duration
        _counts[name] += 1
    if name == "compile_s" and _pending:
        _pending.pop(0)[3] = duration


def _watch_the_persistent_cache() -> None:
    """Wraps JAX's persistent-cache hit and miss loggers (private, JAX 0.10) to learn
    each program's name and key; without them the per-program log stays empty."""
    from jax._src import compiler

    for outcome in ("hit", "miss"):
        name = f"log_persistent_cache_{outcome}"
        logger = getattr(compiler, name, None)
        if logger is None or getattr(logger, "_suite_profile", False):
            continue

        def wrapped(module_name: str, cache_key: str, *, _log=logger, _outcome=outcome) -> None:
            row = [module_name, cache_key, _outcome, 0.0]
            _programs.append(row)
            if _outcome == "miss":
                _pending.append(row)
            _log(module_name, cache_key)

        wrapped._suite_profile = True  # type: ignore[attr-defined]
        setattr(compiler, name, wrapped)


class _Recorder:
    """The plugin proper: one TSV line per test to ``path``."""

    def __init__(self, path: Path, programs: Path) -> None:
        self.path = path
        self.programs = programs

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item: Any, nextitem: Any) -> Any:
        _seconds.clear()
        _counts.clear()
        _programs.clear()
        _pending.clear()
        maps = memory_maps()
        start = time.perf_counter()
        yield
        values = [f"{time.perf_counter() - start:.3f}"]
        for name in EVENTS.values():
            values += [f"{_seconds[name]:.3f}", str(_counts[name])]
        values.append(str(memory_maps() - maps))
        with open(self.path, "a", encoding="utf-8") as f:
            f.write("\t".join([item.nodeid, *values]) + "\n")
        with open(self.programs, "a", encoding="utf-8") as f:
            for program, key, outcome, seconds in _programs:
                f.write(f"{item.nodeid}\t{program}\t{key}\t{outcome}\t{seconds:.3f}\n")


def pytest_configure(config: pytest.Config) -> None:
    """Registers the listener and the recorder in this process (the xdist controller
    runs no test: its file stays empty)."""
    from jax import monitoring

    monitoring.register_event_duration_secs_listener(_listen)
    _watch_the_persistent_cache()
    out = Path(os.environ.get("SUITE_PROFILE_DIR", DEFAULT_DIR))
    out.mkdir(parents=True, exist_ok=True)
    pid = os.getpid()
    recorder = _Recorder(out / f"suite-{pid}.tsv", out / f"compiles-{pid}.tsv")
    config.pluginmanager.register(recorder, "suite-recorder")


def read_rows(paths: Iterable[Path]) -> list[dict[str, Any]]:
    """Every test's row of the plugin's TSV files, with ``worker`` (the file's stem)."""
    rows = []
    for path in paths:
        for line in path.read_text(encoding="utf-8").splitlines():
            cells = line.split("\t")
            row: dict[str, Any] = {"worker": path.stem, "test": cells[0]}
            for field, cell in zip(FIELDS[1:], cells[1:], strict=True):
                row[field] = int(cell) if field in COUNTS else float(cell)
            rows.append(row)
    return rows


def read_programs(paths: Iterable[Path]) -> list[dict[str, Any]]:
    """Every line of the plugin's ``compiles-*.tsv`` files, with ``worker``."""
    rows = []
    for path in paths:
        for line in path.read_text(encoding="utf-8").splitlines():
            row: dict[str, Any] = dict(zip(PROGRAM_FIELDS, line.split("\t"), strict=True))
            row["compile_s"] = float(row["compile_s"])
            rows.append({"worker": path.stem, **row})
    return rows


def by_program(programs: Sequence[dict[str, Any]], group: str) -> list[dict[str, Any]]:
    """Compiles (cache misses) grouped by ``group`` (``"key"``: the same program;
    ``"program"``: one name's every key), most compile seconds first; each with its
    compiles, distinct keys, hits, seconds and the test files that compiled it."""
    groups: dict[str, dict[str, Any]] = {}
    for row in programs:
        into = groups.setdefault(
            row[group],
            {"program": row["program"], "compiles": 0, "hits": 0, "compile_s": 0.0,
             "keys": set(), "files": set()},
        )  # fmt: skip
        if row["outcome"] == "hit":
            into["hits"] += 1
            continue
        into["compiles"] += 1
        into["compile_s"] += row["compile_s"]
        into["keys"].add(row["key"])
        into["files"].add(row["test"].split("::", 1)[0])
    out = [
        {**g, "keys": len(g["keys"]), "files": ", ".join(sorted(g["files"]))}
        for g in groups.values()
    ]
    return sorted(out, key=lambda g: -g["compile_s"])


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


PROGRAM_COLUMNS = {
    "program": "program",
    "compiles": "compiles",
    "keys": "distinct keys",
    "hits": "cache hits",
    "compile_s": "XLA compile s",
    "files": "compiled in",
}


def program_tables(programs: Sequence[dict[str, Any]], top: int) -> dict[str, Any]:
    """The programs compiled more than once under one key (``repeated``) and the
    functions compiled under the most keys (``names``), ``top`` of each."""
    repeated = [g for g in by_program(programs, "key") if g["compiles"] > 1]
    names = by_program(programs, "program")
    return {"repeated": repeated[:top], "names": names[:top]}


COLUMNS = {
    "file": "test file",
    "tests": "tests",
    "wall_s": "wall s",
    "compile_s": "XLA compile s",
    "compile_s_n": "compiles",
    "trace_s": "trace s",
    "lower_s": "lower s",
    "cache_hit_s_n": "cache hits",
    "maps_added": "memory maps added",
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
    programs = read_programs(sorted(Path(args.dir).glob("compiles-*.tsv")))
    result.update(program_tables(programs, args.top))
    total = result["total"]
    lines = [
        f"{result['tests']} tests; worker time {total['wall_s']:.0f} s "
        f"({', '.join(f'{w} {s:.0f} s' for w, s in sorted(result['workers'].items()))}), "
        f"of which XLA compile {total['compile_s']:.0f} s ({total['compile_s_n']} compiles), "
        f"tracing {total['trace_s']:.0f} s, lowering {total['lower_s']:.0f} s, "
        f"{total['cache_hit_s_n']} persistent-cache hits; subprocesses count as wall only.",
        "",
        *markdown_table(result["files"][: args.top], COLUMNS),
        "",
        "Programs compiled more than once (one persistent-cache key):",
        "",
        *markdown_table(result["repeated"], PROGRAM_COLUMNS),
        "",
        "Functions by compile seconds, over all their keys:",
        "",
        *markdown_table(result["names"], PROGRAM_COLUMNS),
    ]
    return report("suite_profile", "Where the test suite's time goes", result, lines, args.out)


if __name__ == "__main__":
    main()
