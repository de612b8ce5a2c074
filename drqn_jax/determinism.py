"""Bit-for-bit reproducibility on CPU: no fused multiply-add in generated code (XLA:CPU contracts
``a + b*c`` into an FMA depending on fusion, i.e. on shapes, so results would change by an ulp
with the batch size). ``import drqn_jax`` appends ``--xla_cpu_max_isa=AVX`` to ``XLA_FLAGS``
unless ``--xla_cpu_max_isa`` is set or ``DRQN_JAX_ALLOW_FMA=1``; only before any JAX computation.
Other shape-independence rules: divide by a scalar parameter as a reciprocal product; ``EnvParams``
behind ``lax.optimization_barrier``; weight gradients from a materialised transpose
(:func:`drqn_jax.layers._rows_product`; Eigen splits ``x.T @ g`` by :func:`cpu_thread_pool_size`);
no ``vmap`` over one run; evaluation batches of exactly :data:`drqn_jax.evaluation.EVAL_BATCH` rows
(kernels are picked by rows)."""

import os
import re
import warnings

DETERMINISM_FLAG = "--xla_cpu_max_isa=AVX"
OPT_OUT_VARIABLE = "DRQN_JAX_ALLOW_FMA"


def fma_disabled() -> bool:
    """Whether ``XLA_FLAGS`` caps CPU code generation below FMA."""
    flags = os.environ.get("XLA_FLAGS", "")
    return any(f"--xla_cpu_max_isa={isa}" in flags for isa in ("AVX", "SSE4_2")) and not any(
        f"--xla_cpu_max_isa={isa}" in flags for isa in ("AVX2", "AVX512", "AVX512F")
    )


def cpu_thread_pool_size() -> int:
    """Threads of XLA:CPU's pool, sized as the PJRT CPU client does."""
    for name in ("PJRT_NPROC", "NPROC"):
        try:
            nproc = max(0, int(os.environ[name]))
            break
        except (KeyError, ValueError):
            continue
    else:  # neither variable holds a number
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
    try:  # whether JAX has started its backend
        from jax._src import xla_bridge

        started = bool(getattr(xla_bridge, "_backends", {}))
    except Exception:  # private API moved: assume the worst case cannot be detected
        started = False
    os.environ["XLA_FLAGS"] = f"{flags} {DETERMINISM_FLAG}".strip()
    if started:
        warnings.warn(
            f"drqn_jax was imported after JAX started its backend: {DETERMINISM_FLAG} (no "
            "FMA) is not in effect, results may differ by an ulp with the batch size. Import "
            f"drqn_jax first, or set XLA_FLAGS={DETERMINISM_FLAG}.",
            RuntimeWarning,
            stacklevel=3,
        )
