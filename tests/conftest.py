"""Shared fixtures. drqn_jax is imported first so its XLA flags take effect.

The suite compiles the same programs in several processes (pytest-xdist
workers, the command-line tests' subprocesses, the forced-device and
multi-process sweeps), so it shares JAX's persistent compilation cache
between them: a directory made for the session (removed at its end) unless
``JAX_COMPILATION_CACHE_DIR`` is already set, in which case that one is used
and kept. A cache hit loads the very executable an earlier compile produced
(the key holds the program, the XLA flags and the JAX version), so results
are the same bits; only compile time is saved. Every compile is kept, however
short (``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0``, JAX's default keeps
those over a second): the suite's eager calls compile the same small programs
again and again (an eager ``lax.cond`` is traced afresh at each call, so JAX's
in-memory cache misses it, so the same program would be compiled at every
call), and both workers and the subprocesses compile
the same op-by-op programs; from the persistent cache each is compiled once.

Each pytest-xdist worker gets its share of the cores as its XLA:CPU thread pool
(``PJRT_NPROC``: cores // workers, at least 1, unless ``PJRT_NPROC`` is set): with
the default pool (every core) in every worker, 2 workers on 2 cores run 4 pool
threads that contend for the cores. Results do not depend on the pool's size
(:mod:`drqn_jax.determinism`; the 4-device and 2-process tests run a bigger pool
than their parent's and compare every bit).

No test file needs to drop compiled programs to stay under Linux's
``vm.max_map_count``: :mod:`drqn_jax.programs` bounds what it holds by memory
maps, and over its budget clears JAX's own caches first (where the tests' own
``jax.jit``s and eager ops keep their executables); the package keeps no jitted
function with static arguments outside it.
"""

import os
import shutil
import tempfile

import jax
import pytest

import drqn_jax
from drqn_jax.determinism import cpu_thread_pool_size

_CACHE_VARIABLE = "JAX_COMPILATION_CACHE_DIR"
_MIN_TIME_VARIABLE = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"
_made_cache = pytest.StashKey[str]()


def _share_the_cores() -> None:
    """An xdist worker's ``PJRT_NPROC``: the usable cores over the workers."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers > 1 and "PJRT_NPROC" not in os.environ:
        os.environ["PJRT_NPROC"] = str(max(1, cpu_thread_pool_size() // workers))


def pytest_configure(config: pytest.Config) -> None:
    # The controller (or the only process) makes the directory; xdist workers and
    # subprocesses inherit the variable.
    if _CACHE_VARIABLE not in os.environ:
        path = tempfile.mkdtemp(prefix="drqn-jax-test-xla-cache-")
        os.environ[_CACHE_VARIABLE] = path
        config.stash[_made_cache] = path
    os.environ.setdefault(_MIN_TIME_VARIABLE, "0")
    _share_the_cores()  # before this worker's CPU backend starts
    # jax was imported (by drqn_jax) before the variables were set in this process.
    jax.config.update("jax_compilation_cache_dir", os.environ[_CACHE_VARIABLE])
    jax.config.update(
        "jax_persistent_cache_min_compile_time_secs", float(os.environ[_MIN_TIME_VARIABLE])
    )


def pytest_unconfigure(config: pytest.Config) -> None:
    path = config.stash.get(_made_cache, None)
    if path is not None:
        shutil.rmtree(path, ignore_errors=True)


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
