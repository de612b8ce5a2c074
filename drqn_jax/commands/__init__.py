"""The ``drqn-jax`` commands: :mod:`drqn_jax.cli` parses, ``cmd_<name>(args)`` returns
the exit status."""

import datetime
import sys
from pathlib import Path

from drqn_jax.config import Config


def say(text: str) -> None:
    """A status line on stderr (stdout holds the results)."""
    print(text, file=sys.stderr, flush=True)


def default_run_dir(prefix: str, config_name: str) -> Path:
    """``runs/<prefix>-<config>-<UTC time>``: where a command writes when not told."""
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{prefix}-{Path(config_name).stem}-{stamp}"


def duration_text(seconds: float) -> str:
    """``42 s``, ``17 min`` or ``3 h 05 min``: a wall time as a person reads it."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{minutes} min"


def evaluation_overrides(
    overrides: list[str], episodes: int | None = None, seed: int | None = None
) -> list[str]:
    """``overrides`` (--set), then --episodes and --seed as evaluate.episodes and run.seed."""
    given = {"evaluate.episodes": episodes, "run.seed": seed}
    return [*overrides, *(f"{name}={value}" for name, value in given.items() if value is not None)]


def episodes_text(config: Config) -> str:
    """``N episodes of ENV_ID (evaluation key of seed S)``: the episodes an agent plays."""
    return (
        f"{config['evaluate']['episodes']} episodes of {config['env']['id']} "
        f"(evaluation key of seed {config['run']['seed']})"
    )
