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
"""

from __future__ import annotations

import collections
import functools
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

__all__ = ["MAX_PROGRAMS", "cached", "cached_program", "clear_programs", "program_counts"]

#: Entries kept before the least recently used is dropped. Each may hold compiled
#: executables of several MB, and each live XLA:CPU executable maps memory (Linux
#: stops a process at ``vm.max_map_count`` maps); a sweep builds a few per shape.
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


def program_counts() -> dict[str, int]:
    """How many entries each builder (by qualified name) holds now."""
    return dict(collections.Counter(name for name, _ in _STORE))


def clear_programs() -> None:
    """Drop every built program (they are rebuilt, and recompiled, on next use)."""
    _STORE.clear()
