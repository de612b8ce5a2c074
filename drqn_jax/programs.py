"""The one LRU cache of built programs (trainers, jitted env and agent functions): ``jit`` compiles
once per function object, so everything built from a hashable description goes through
:func:`cached_program` or :func:`cached`. Over :func:`map_budget` memory maps (Linux kills a process
at ``vm.max_map_count``), JAX's caches and then the older half of the store are dropped; rebuilt,
same bits."""

import collections
import functools
import gc
import inspect
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

import jax

#: Entries kept before the least recently used is dropped.
MAX_PROGRAMS = 64

F = TypeVar("F", bound=Callable[..., Any])

_STORE: collections.OrderedDict[tuple[str, Hashable], Any] = collections.OrderedDict()


def cached(name: str, key: Hashable, build: Callable[[], Any]) -> Any:
    """The program ``name`` for ``key``: ``build()``'s result, built on first use."""
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
    """``builder`` (hashable arguments) built once per set of arguments, in the store."""
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
    """Half of Linux's ``vm.max_map_count`` (headroom until the next build checks)."""
    try:
        with open("/proc/sys/vm/max_map_count") as limit:
            return int(limit.read()) // 2
    except (OSError, ValueError):
        return 32_765


def _drop_while_over_map_budget() -> None:
    """Over budget, drop JAX's caches, then the older half of the store until under."""
    if memory_maps() <= map_budget():
        return
    jax.clear_caches()
    gc.collect()
    while _STORE and memory_maps() > map_budget():
        for _ in range(max(1, len(_STORE) // 2)):
            _STORE.popitem(last=False)
        gc.collect()  # a jitted function and its executables may sit in a cycle


def jit_in_store(*static_argnames: str) -> Callable[[F], F]:
    """``partial(jax.jit, static_argnames=...)`` whose programs live in the store."""

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
