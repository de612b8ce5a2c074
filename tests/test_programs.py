"""The one cache of built programs (drqn_jax/programs.py)."""

from __future__ import annotations

import collections
import re
from pathlib import Path

import jax
import numpy as np

from drqn_jax import programs
from drqn_jax.agents import drqn_agent
from drqn_jax.networks import NetworkConfig, make_network
from drqn_jax.programs import cached_program

PACKAGE = Path(programs.__file__).parent


def program_counts() -> dict[str, int]:
    """How many entries each builder (by qualified name) holds."""
    return dict(collections.Counter(name for name, _ in programs._STORE))


def clear_programs() -> None:
    """Drop every built program (they are rebuilt, and recompiled, on next use)."""
    programs._STORE.clear()


def test_a_builder_builds_once_per_arguments_and_evicts_the_least_recent(monkeypatch):
    built = []

    @cached_program
    def build(x, scale=1):
        built.append((x, scale))
        return object()

    clear_programs()
    assert build(1) is build(1) and build(1, scale=2) is not build(1)
    assert built == [(1, 1), (1, 2)]
    assert program_counts() == {f"{__name__}.{build.__qualname__}": 2}
    monkeypatch.setattr(programs, "MAX_PROGRAMS", 3)
    build(2)
    build(1)  # used again: now the most recent
    build(3), build(4)  # two more: (1, scale=2) and 2 go, 1 stays
    built.clear()
    build(1), build(2)
    assert built == [(2, 1)]


def test_over_the_map_budget_the_least_recent_half_goes(monkeypatch):
    @cached_program
    def build(x):
        return object()

    clear_programs()
    for x in range(6):
        build(x)
    # over a budget of 5 maps while more than 3 programs are held
    monkeypatch.setattr(programs, "map_budget", lambda: 5)
    monkeypatch.setattr(programs, "memory_maps", lambda: 10 if len(programs._STORE) > 3 else 0)
    build(6)  # 6 held, over budget: 0, 1, 2 go, then 6 joins
    assert [key[1][0][0] for key in programs._STORE] == [3, 4, 5, 6]
    build(3)  # held: no check, nothing goes
    assert len(programs._STORE) == 4
    monkeypatch.undo()
    assert programs.memory_maps() > 0 and programs.map_budget() > 1000


def test_over_the_map_budget_jaxs_own_caches_go_before_the_store(monkeypatch):
    """A function jitted outside the store holds its executable in JAX's cache; over
    the budget that goes first, and the store keeps what it holds once under it."""
    outside = jax.jit(lambda x: x + 1)
    outside(np.float32(1.0))
    assert outside._cache_size() == 1

    @cached_program
    def build(x):
        return object()

    clear_programs()
    build(0)
    cleared, clear_caches = [], jax.clear_caches
    monkeypatch.setattr(jax, "clear_caches", lambda: cleared.append(clear_caches()))
    monkeypatch.setattr(programs, "memory_maps", lambda: 0 if cleared else 10**6)
    build(1)
    assert len(cleared) == 1 and outside._cache_size() == 0
    assert [key[1][0][0] for key in programs._STORE] == [0, 1]


def test_jit_in_store_jits_once_per_static_value_in_the_store():
    traced = []

    @programs.jit_in_store("power")
    def raise_to(x, power=2):
        traced.append(power)
        return x**power

    clear_programs()
    x = jax.numpy.float32(3.0)
    assert float(raise_to(x)) == 9.0 and float(raise_to(x, power=2)) == 9.0
    assert float(raise_to(x, 3)) == 27.0 and float(raise_to(2 * x, 3)) == 216.0
    assert traced == [2, 3]  # one trace per static value, the same program reused
    assert program_counts() == {f"{__name__}.{raise_to.__qualname__}": 2}
    clear_programs()
    assert float(raise_to(x, 3)) == 27.0 and traced == [2, 3, 3]


def test_the_same_network_config_gives_the_same_functions_and_agents():
    config = NetworkConfig(recurrent=8, hidden=8)
    net = make_network(config)
    assert make_network(config) is net
    params = net.init(jax.random.key(0))
    a, b = drqn_agent(net, params), drqn_agent(net, params)
    assert (a.init_fn, a.act_fn) == (b.init_fn, b.act_fn)  # one jit compilation for both


def test_cleared_programs_rebuild_with_identical_results():
    config = NetworkConfig(recurrent=8, hidden=8)
    net = make_network(config)
    params = net.init(jax.random.key(0))
    clear_programs()
    rebuilt = make_network(config)
    assert rebuilt is not net and not program_counts().get("drqn_jax.agents.base._greedy_functions")
    same = jax.tree.map(np.array_equal, rebuilt.init(jax.random.key(0)), params)
    assert all(jax.tree.leaves(same))


def test_the_package_caches_programs_only_there():
    """No second cache: functools.cache / lru_cache, module-level dicts filled at
    run time (``_NAME: dict[...] = {}``) and module-level jits with static arguments
    (an executable per static value for the life of the process: ``jit_in_store``
    instead) are gone from every module but programs.py."""
    pattern = re.compile(
        r"functools\.(lru_)?cache\b|@(lru_)?cache\b|^_[A-Z_]+: dict\[.*\] = \{\}"
        r"|^@(functools\.)?partial\(jax\.jit, static|^\w+ = jax\.jit\(.*static",
        re.M,
    )
    found = [
        str(path.relative_to(PACKAGE))
        for path in PACKAGE.rglob("*.py")
        if path.name != "programs.py" and pattern.search(path.read_text())
    ]
    assert found == []
