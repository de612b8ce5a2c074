"""Trained agents shipped with the package (``drqn-jax evaluate --agent NAME``, ``replay
--agent NAME``): each a directory ``trained/<NAME>/`` as ``drqn-jax export`` writes it
(``config.toml``, ``agent.npz``/``agent.json``, ``provenance.json``)."""

from pathlib import Path

#: Where the shipped agents live (package data).
TRAINED_DIR = Path(__file__).resolve().parent / "trained"


def shipped_agents() -> tuple[str, ...]:
    """The shipped agents' names, sorted (directories of :data:`TRAINED_DIR` with ``agent.npz``)."""
    if not TRAINED_DIR.is_dir():
        return ()
    return tuple(sorted(p.parent.name for p in TRAINED_DIR.glob("*/agent.npz")))


def shipped_agent_dir(name: str) -> Path:
    """The directory of the shipped agent ``name``; ValueError naming those there are."""
    if name not in shipped_agents():
        there = ", ".join(shipped_agents()) or "none"
        raise ValueError(f"no shipped agent {name!r} (shipped: {there})")
    return TRAINED_DIR / name
