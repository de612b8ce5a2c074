"""Shared fixtures. drqn_jax is imported first so its XLA flags take effect.

The suite compiles the same programs in several processes (pytest-xdist
workers, the command-line tests' subprocesses, the forced-device and
multi-process sweeps), so it shares JAX's persistent compilation cache
between them: a directory made for the session (removed at its end) unless
``JAX_COMPILATION_CACHE_DIR`` is already set, in which case that one is used
and kept. A cache hit loads the very executable an earlier compile produced
(the key holds the program, the XLA flags and the JAX version), so results
are the same bits; only compile time is saved.

Each worker also keeps its live compiled programs bounded: every XLA:CPU
executable maps code and data into the process, and Linux ends a process that
reaches ``vm.max_map_count`` (65,530 by default) with a crash inside XLA. After
a test file, a worker holding more than :data:`MAP_BUDGET` memory maps drops its
compiled programs (JAX's caches and :mod:`drqn_jax.programs`); the next file
recompiles, mostly from the persistent cache.
"""

import gc
import os
import shutil
import tempfile

import jax
import pytest

import drqn_jax
from drqn_jax.programs import clear_programs

#: Memory maps a worker may hold after a test file before it drops its programs.
MAP_BUDGET = 30_000

_CACHE_VARIABLE = "JAX_COMPILATION_CACHE_DIR"
_made_cache = pytest.StashKey[str]()


def pytest_configure(config: pytest.Config) -> None:
    # The controller (or the only process) makes the directory; xdist workers and
    # subprocesses inherit the variable.
    if _CACHE_VARIABLE not in os.environ:
        path = tempfile.mkdtemp(prefix="drqn-jax-test-xla-cache-")
        os.environ[_CACHE_VARIABLE] = path
        config.stash[_made_cache] = path
    # jax was imported (by drqn_jax) before the variable was set in this process.
    jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_VARIABLE])


def pytest_unconfigure(config: pytest.Config) -> None:
    path = config.stash.get(_made_cache, None)
    if path is not None:
        shutil.rmtree(path, ignore_errors=True)


def _memory_maps() -> int:
    """This process's memory maps (Linux; 0 where /proc is not there)."""
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


@pytest.fixture(autouse=True, scope="module")
def _bounded_compiled_programs():
    """After each test file: drop the compiled programs if the maps near the limit."""
    yield
    if _memory_maps() > MAP_BUDGET:
        clear_programs()
        jax.clear_caches()
        gc.collect()


@pytest.fixture(scope="session")
def env_params():
    """``drqn_jax.make("UrbanPedestrians-v0")``: one env and its default params."""
    return drqn_jax.make("UrbanPedestrians-v0")


@pytest.fixture(scope="session")
def env(env_params):
    """The paper's world (``env_params``' env); a module may define its own ``env``."""
    return env_params[0]


@pytest.fixture(scope="session")
def params(env_params):
    """The paper's world's default ``EnvParams``."""
    return env_params[1]


@pytest.fixture(scope="session")
def static(env):
    """The paper's world's ``StaticEnvParams``."""
    return env.static
