"""Bit-for-bit reproducibility on CPU: no fused multiply-add in generated code.

XLA:CPU lets LLVM contract ``a + b*c`` into one fused multiply-add (FMA)
wherever both sit in one generated loop. Whether they do depends on how a
program was fused and vectorised, i.e. on the shapes: the same episode then
drifts by an ulp depending on how many environments run beside it, and
``jit`` differs from eager execution. Capping the code generator at AVX
(``--xla_cpu_max_isa=AVX``, which has no FMA instructions) removes the
contraction, so per-episode results are bit-identical whatever the batch.
Measured cost on the 2-core CPU (``benchmarks/env_throughput.py``): 3-4 % of
env throughput at 4096 environments, about 20 % at 1024.

``import drqn_jax`` appends the flag to ``XLA_FLAGS`` unless

* ``XLA_FLAGS`` already sets ``--xla_cpu_max_isa`` (the user's choice wins), or
* ``DRQN_JAX_ALLOW_FMA=1`` is set (faster, not batch-independent).

Two more habits keep results independent of the program's shape, and the
simulator follows both: a division by a scalar parameter is written as a
multiplication by its reciprocal (XLA rewrites ``x / broadcast(c)`` that way
in batched programs but not for scalars), and the env hides ``EnvParams``
behind ``lax.optimization_barrier`` so that closing over them (constants)
and passing them (arguments) compile to the same arithmetic.

XLA reads its flags when the CPU backend starts, so this only takes effect
if no JAX computation ran before ``import drqn_jax``; otherwise a warning says so.

Two more things fix the rounding of matrix products (measured, issues 6 and 51):

* **XLA:CPU's thread pool.** It has ``max(PJRT_NPROC, forced host devices)``
  threads, ``PJRT_NPROC`` defaulting to the usable cores
  (:func:`cpu_thread_pool_size`). XLA:CPU gives a product that contracts its
  left operand's leading axis (``x.T @ g``: autodiff's weight gradients) to
  Eigen, which splits its sums by the pool size, so 4 forced host devices on
  2 cores (a pool of 4, not 2) trained other weights. Every other product goes
  to YNNPACK, whose sums do not depend on the pool, so the network computes
  its weight gradients from a materialised transpose
  (:func:`drqn_jax.layers._rows_product`): results are the same whatever the
  pool, hence whatever the device count, ``PJRT_NPROC`` or core count. The
  copy costs some speed on the CPU (measured in ``benchmarks/RESULTS.md``,
  "Device-invariant weight gradients").
  ``--xla_cpu_multi_thread_eigen=false`` does not help: XLA:CPU's runtime
  hands Eigen the pool regardless (checked with jax 0.10.2).
* **No batch of one.** A ``vmap`` over one element compiles unbatched
  products that round differently from the batched ones; the sweep runner
  never gives a device a single run.
* **No small batch of episodes.** YNNPACK picks its matrix kernel by the
  number of rows: the shipped network's 768-wide GRU products and its 4-wide
  Q head round differently with fewer than about 61 and 81 rows than with
  more (measured, whatever the thread pool). So every evaluation batch (and a
  recording's decisions) runs at least :data:`drqn_jax.evaluation.MIN_BATCH`
  episodes, padding included: episode i then has the same bits whatever the
  number of episodes or ``evaluate.batch_size`` (0 or >= ``MIN_BATCH``).
"""

from __future__ import annotations

import os
import re
import warnings

DETERMINISM_FLAG = "--xla_cpu_max_isa=AVX"
OPT_OUT_VARIABLE = "DRQN_JAX_ALLOW_FMA"

__all__ = ["DETERMINISM_FLAG", "configure_xla_flags", "cpu_thread_pool_size", "fma_disabled"]


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge

        return bool(getattr(xla_bridge, "_backends", {}))
    except Exception:  # private API moved: assume the worst case cannot be detected
        return False


def fma_disabled() -> bool:
    """Whether ``XLA_FLAGS`` caps CPU code generation below FMA."""
    flags = os.environ.get("XLA_FLAGS", "")
    return any(f"--xla_cpu_max_isa={isa}" in flags for isa in ("AVX", "SSE4_2")) and not any(
        f"--xla_cpu_max_isa={isa}" in flags for isa in ("AVX2", "AVX512", "AVX512F")
    )


def cpu_thread_pool_size() -> int:
    """Threads of XLA:CPU's pool: ``max(PJRT_NPROC (or NPROC, or the usable cores),
    --xla_force_host_platform_device_count)``, as the PJRT CPU client sizes it."""
    nproc = None
    for name in ("PJRT_NPROC", "NPROC"):
        try:
            nproc = max(0, int(os.environ[name]))
            break
        except (KeyError, ValueError):
            continue
    if nproc is None:
        try:
            nproc = len(os.sched_getaffinity(0))
        except AttributeError:  # not on Linux
            nproc = os.cpu_count() or 1
    match = re.search(
        r"--xla_force_host_platform_device_count=(\d+)", os.environ.get("XLA_FLAGS", "")
    )
    return max(nproc, int(match.group(1)) if match else 1)


def configure_xla_flags() -> None:
    """Append :data:`DETERMINISM_FLAG` to ``XLA_FLAGS`` (see the module docstring)."""
    if os.environ.get(OPT_OUT_VARIABLE) == "1":
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if "--xla_cpu_max_isa" in flags:
        return
    started = _backend_started()
    os.environ["XLA_FLAGS"] = f"{flags} {DETERMINISM_FLAG}".strip()
    if started:
        warnings.warn(
            "drqn_jax was imported after JAX had started its backend, so "
            f"{DETERMINISM_FLAG} (no FMA contraction) is not in effect: results may differ "
            "by an ulp with the batch size. Import drqn_jax before running any JAX "
            f"computation, or set XLA_FLAGS={DETERMINISM_FLAG} yourself.",
            RuntimeWarning,
            stacklevel=3,
        )
