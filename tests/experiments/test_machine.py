"""The machine block every benchmark and study records (drqn_jax/experiments/machine.py)."""

from __future__ import annotations

import io

from drqn_jax.experiments import machine

CPUINFO = """processor\t: 0
vendor_id\t: AuthenticAMD
cpu family\t: 25
model\t\t: 1
model name\t: AMD EPYC
stepping\t: 1
flags\t\t: fpu sse4_2 avx fma avx2 avx512f bmi2

processor\t: 1
cpu family\t: 99
"""


def test_the_cpu_is_named_beyond_its_model_name(monkeypatch):
    """One "AMD EPYC" may be several generations, whose bits differ: the record keeps
    the first processor's family, model, stepping and vector extensions."""
    monkeypatch.setattr(machine, "open", lambda *a, **k: io.StringIO(CPUINFO), raising=False)
    assert machine.cpu_model() == "AMD EPYC"
    assert machine.cpu_identity() == "family 25 model 1 stepping 1; avx avx2 avx512f fma"
    info = {**machine.machine_info(), "cpu_model": "AMD EPYC"}
    assert machine.machine_lines(info)[0] == (
        "- CPU: AMD EPYC (family 25 model 1 stepping 1; avx avx2 avx512f fma)"
    )


def test_a_machine_without_proc_cpuinfo_says_so(monkeypatch):
    def missing(*args, **kwargs):
        raise OSError("no /proc")

    monkeypatch.setattr(machine, "open", missing, raising=False)
    assert machine.cpu_identity() == "(unknown)"


def test_a_cpu_device_is_named_by_its_cpu(monkeypatch):
    monkeypatch.setattr(machine, "open", lambda *a, **k: io.StringIO(CPUINFO), raising=False)
    assert machine.device_identity() == (
        "AMD EPYC (family 25 model 1 stepping 1; avx avx2 avx512f fma)"
    )
