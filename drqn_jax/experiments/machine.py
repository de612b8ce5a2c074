"""The machine block every benchmark prints beside its figures."""

import datetime
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

import jax
import jaxlib

import drqn_jax
from drqn_jax.determinism import cpu_thread_pool_size, fma_disabled


def _first_processor() -> dict[str, str]:
    """The first processor's /proc/cpuinfo fields (lower-case keys); empty if absent."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            first = f.read().split("\n\n")[0]
    except OSError:
        return {}
    lines = (line.partition(":") for line in first.splitlines())
    return {key.strip().lower(): value.strip() for key, _, value in lines}


def cpu_model() -> str:
    """The CPU's "model name" from /proc/cpuinfo, else ``platform.processor()``."""
    return _first_processor().get("model name") or platform.processor() or "(unknown)"


def cpu_identity() -> str:
    """``family 25 model 1 stepping 1; avx avx2 fma`` from /proc/cpuinfo, or "(unknown)":
    results are bit-identical only on one such CPU (docs/guide.md)."""
    fields = _first_processor()
    if not fields:
        return "(unknown)"
    names = {"cpu family": "family", "model": "model", "stepping": "stepping"}
    ident = " ".join(f"{name} {fields[k]}" for k, name in names.items() if k in fields)
    vector = sorted(f for f in fields.get("flags", "").split() if f.startswith("avx") or f == "fma")
    return f"{ident}; {' '.join(vector) or 'no avx'}"


def device_identity() -> str:
    """The CPU's model name and :func:`cpu_identity`, or the accelerator's kind."""
    device = jax.devices()[0]
    if device.platform == "cpu":
        return f"{cpu_model()} ({cpu_identity()})"
    return device.device_kind


#: A record's device or commit where it predates keeping them.
NOT_RECORDED = "(not recorded)"


def git_commit() -> str:
    """``HEAD``'s short hash of this checkout, ``+dirty`` if ``drqn_jax/`` has edits."""
    root = Path(__file__).resolve().parents[2]  # the checkout: drqn_jax/experiments/..

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True)

    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", "drqn_jax")
    except OSError:
        return "(unknown)"
    if head.returncode != 0:
        return "(unknown)"
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def machine_info() -> dict[str, Any]:
    """What the numbers depend on: CPU, cores, JAX versions, devices, XLA flags, date."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    devices = jax.devices()
    return {
        "cpu_model": cpu_model(),
        "cpu_identity": cpu_identity(),
        "logical_cores": os.cpu_count(),
        "usable_cores": usable,
        "jax_version": jax.__version__,
        "jaxlib_version": jaxlib.__version__,
        "platform": devices[0].platform,
        "devices": [str(d) for d in devices],
        "device": device_identity(),
        # as in effect: import drqn_jax disables FMA unless opted out (drqn_jax.determinism)
        "xla_flags": os.environ.get("XLA_FLAGS", "(unset)"),
        "fma_disabled": fma_disabled(),
        "xla_cpu_threads": cpu_thread_pool_size(),
        "drqn_jax_allow_fma": os.environ.get("DRQN_JAX_ALLOW_FMA", "(unset)"),
        "compilation_cache_dir": jax.config.jax_compilation_cache_dir or "(off)",
        "drqn_jax_version": drqn_jax.__version__,
        "git_commit": git_commit(),
        "python_version": platform.python_version(),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "loadavg_1min_at_start": os.getloadavg()[0],
    }


def machine_lines(info: dict[str, Any]) -> list[str]:
    """The machine block as Markdown bullet lines."""
    return [
        f"- CPU: {info['cpu_model']} ({info['cpu_identity']})",
        f"- logical cores (os.cpu_count()): {info['logical_cores']}"
        f" (usable by this process: {info['usable_cores']})",
        f"- JAX {info['jax_version']}, jaxlib {info['jaxlib_version']}",
        f"- jax.devices(): platform {info['platform']}, {', '.join(info['devices'])}",
        f"- XLA_FLAGS (after import drqn_jax): {info['xla_flags']}"
        f" (FMA {'disabled' if info['fma_disabled'] else 'allowed'};"
        f" DRQN_JAX_ALLOW_FMA: {info['drqn_jax_allow_fma']})",
        f"- XLA:CPU thread pool: {info['xla_cpu_threads']} threads (PJRT_NPROC: "
        f"{os.environ.get('PJRT_NPROC', '(unset)')})",
        f"- JAX persistent compilation cache: {info['compilation_cache_dir']}"
        " (when on, a compile time may be the load of an earlier compile)",
        f"- drqn_jax {info['drqn_jax_version']}, git commit {info['git_commit']}",
        f"- Python {info['python_version']}",
        f"- date (UTC): {info['date']}",
        f"- load average (1 min) when this block was written: {info['loadavg_1min_at_start']:.2f}",
    ]
