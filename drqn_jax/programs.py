"""The one cache of built programs: trainers, jitted env functions, agent functions.

``jit`` compiles once per function object and argument shapes, so a program is
compiled once only if the function behind it is built once. Everything the
package builds from static (hashable) descriptions — a :class:`~drqn_jax.learners.trainer.Trainer`
per ``TrainConfig``, the Gymnasium env's jitted reset/step/render per static env,
a DRQN agent's ``init``/``act`` per network, a compiled training chunk per
program key — goes through :func:`cached_program` (or :func:`cached`),
into one least-recently-used store of at most :data:`MAX_PROGRAMS` entries.
:func:`program_counts` says what it holds; :func:`clear_programs` empties it (the
next use rebuilds and recompiles, with identical results).

The store is also bounded by memory maps. Each live XLA:CPU executable maps
about three regions (code, constants, data) per kernel it was compiled into:
a tiny trainer's training program holds about 2,400 maps, a paper-preset one
more. Linux ends a process that reaches ``vm.max_map_count`` (65,530 by default)
with a crash inside XLA, and 64 trainers would pass it. So before each build,
while the process holds more than :func:`map_budget` maps, the least recently
used half of the store is dropped (an executable's maps go with its last
reference), after JAX's own caches, which hold the executables of every function
jitted outside the store. A program used again is rebuilt, and its executable
loaded from JAX's persistent cache when that is on; results are the same bits.
"""

from __future__ import annotations

import collections
import functools
import gc
import inspect
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

import jax

__all__ = [
    "MAX_PROGRAMS",
    "cached",
    "cached_program",
    "clear_programs",
    "jit_in_store",
    "map_budget",
    "memory_maps",
    "program_counts",
]

#: Entries kept before the least recently used is dropped (each may hold compiled
#: executables of several MB; the memory maps they hold bound the store too).
MAX_PROGRAMS = 64

F = TypeVar("F", bound=Callable[..., Any])

_STORE: collections.OrderedDict[tuple[str, Hashable], Any] = collections.OrderedDict()


def cached(name: str, key: Hashable, build: Callable[[], Any]) -> Any:
    """The program ``name`` for ``key``: ``build()``'s result, built on first use (for
    programs built from unhashable inputs, e.g. lowered for a given state)."""
    entry = (name, key)
    if entry in _STORE:
        _STORE.move_to_end(entry)
        return _STORE[entry]
    _drop_while_over_map_budget()
    built = _STORE[entry] = build()
    while len(_STORE) > MAX_PROGRAMS:
        _STORE.popitem(last=False)
    return built


def cached_program(builder: F) -> F:
    """Decorate ``builder`` (hashable arguments only) so that each set of arguments
    builds once, kept in the one store under the builder's qualified name. Arguments
    count as given: ``f(x)`` and ``f(config=x)`` are two entries."""
    name = f"{builder.__module__}.{builder.__qualname__}"

    @functools.wraps(builder)
    def built(*args: Hashable, **kwargs: Hashable) -> Any:
        key = (args, tuple(sorted(kwargs.items())))
        return cached(name, key, lambda: builder(*args, **kwargs))

    return built  # type: ignore[return-value]


def memory_maps() -> int:
    """The memory maps this process holds (Linux; 0 where ``/proc`` is not there)."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


@functools.cache
def map_budget() -> int:
    """Maps the process may hold before JAX's caches and the store's programs are
    dropped: half of Linux's ``vm.max_map_count`` (32,765 by default), leaving the
    other half as headroom for the programs compiled until the next build checks."""
    try:
        with open("/proc/sys/vm/max_map_count") as limit:
            return int(limit.read()) // 2
    except (OSError, ValueError):
        return 32_765


def _drop_while_over_map_budget() -> None:
    """Over the budget, drop JAX's own caches, then the least recently used half of the
    store until the maps are under budget.

    JAX's caches keep an executable for every function a process ever jitted outside
    the store (a test suite's, a notebook's, the eager ops'), most of the maps of a
    process that compiles many. Cleared, those are recompiled (or loaded from the
    persistent cache) on next use, with the same bits.
    """
    if memory_maps() <= map_budget():
        return
    jax.clear_caches()
    gc.collect()
    while _STORE and memory_maps() > map_budget():
        for _ in range(max(1, len(_STORE) // 2)):
            _STORE.popitem(last=False)
        gc.collect()  # a jitted function and its executables may sit in a cycle


def jit_in_store(*static_argnames: str) -> Callable[[F], F]:
    """``partial(jax.jit, static_argnames=...)`` whose programs live in the store.

    A module-level ``jax.jit`` keeps an executable for every value of its static
    arguments for the life of the process, out of the store's reach. Decorated
    with this instead, ``fun`` is jitted once per value of ``static_argnames``
    (those values closed over, so the same program) and each jitted function is
    a store entry, dropped with the least recently used.
    """

    def decorate(fun: F) -> F:
        name = f"{fun.__module__}.{fun.__qualname__}"
        signature = inspect.signature(fun)

        @functools.wraps(fun)
        def call(*args: Any, **kwargs: Any) -> Any:
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            static = {k: bound.arguments.pop(k) for k in static_argnames}
            key = tuple(static.items())
            jitted = cached(name, key, lambda: jax.jit(functools.partial(fun, **static)))
            return jitted(**bound.arguments)

        return call  # type: ignore[return-value]

    return decorate


def program_counts() -> dict[str, int]:
    """How many entries each builder (by qualified name) holds now."""
    return dict(collections.Counter(name for name, _ in _STORE))


def clear_programs() -> None:
    """Drop every built program (they are rebuilt, and recompiled, on next use)."""
    _STORE.clear()
