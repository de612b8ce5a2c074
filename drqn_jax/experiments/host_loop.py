"""The one host loop of training: chunks, stop requests, progress and checkpoints.

A compiled chunk (``Trainer.run``: ``chunk_iterations`` iterations under one
``lax.scan``) advances a state on the device; between chunks the host checks
for a stop request (SIGINT/SIGTERM), for a non-finite loss, shows progress and
saves a checkpoint every so often. ``drqn-jax train`` (:mod:`drqn_jax.experiments.runner`,
one run) and sweeps (:mod:`drqn_jax.experiments.sweep_runner`, a call of many runs) both
train through :func:`run_chunks`; what differs — the state, what "finished"
and "healthy" mean, how a checkpoint is written — comes in as functions.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

import jax
import jax.numpy as jnp

__all__ = ["StopRequest", "finite_training", "progress_bar", "run_chunks"]

S = TypeVar("S")


class StopRequest:
    """SIGINT/SIGTERM set a flag checked between chunks; a second signal aborts."""

    def __init__(self) -> None:
        self.signal: int | None = None

    def _handler(self, signum: int, frame: Any) -> None:
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signum
        print(
            f"\n{signal.Signals(signum).name}: stopping after this chunk and saving a checkpoint "
            "(signal again to abort without saving)",
            file=sys.stderr,
            flush=True,
        )

    def request(self) -> None:
        """Stop after this chunk, as a signal would, without a message (signal 0)."""
        self.signal = 0

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopRequest]:
        """Catch SIGINT and SIGTERM while the block runs; the old handlers return after."""
        previous = {s: signal.signal(s, self._handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)


@jax.jit
def finite_training(state: Any) -> jax.Array:
    """() bool: a training state's online parameters, running episode losses and
    recorded losses are all finite (the DQN learner's and PPO's states alike)."""
    leaves = [*jax.tree.leaves(state.online), state.ep_loss_sum, state.metrics["mean_loss"]]
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))


def run_chunks(
    run: Callable[[S], S],
    state: S,
    *,
    finished: Callable[[S], bool],
    stop: StopRequest,
    save: Callable[[S, int], None],
    every_s: float,
    healthy: Callable[[S], bool] | None = None,
    on_chunk: Callable[[S], None] | None = None,
    chunks: int = 0,
) -> tuple[str, S, int]:
    """Run chunks until the state is finished, a stop is requested or it turns unhealthy.

    Args:
        run: one compiled chunk, ``state -> state``.
        finished: whether a state needs no more chunks.
        stop: checked before each chunk.
        save: ``save(state, chunks)``, called every ``every_s`` seconds between chunks
            (not after the last one: the caller saves what it ends with).
        healthy: a new state failing it is dropped and the loop ends (None: all are).
        on_chunk: called with each new state (progress bars).
        chunks: chunks run before (a resumed run counts on).
    Returns:
        ``(status, state, chunks)``: ``"finished"``, ``"interrupted"`` (stop requested)
        or ``"diverged"`` (``state`` is then the last healthy one).
    """
    last_save = time.perf_counter()
    while not finished(state):
        if stop.signal is not None:
            return "interrupted", state, chunks
        new_state = run(state)
        if healthy is not None and not healthy(new_state):
            return "diverged", state, chunks
        state, chunks = new_state, chunks + 1
        if on_chunk is not None:
            on_chunk(state)
        if time.perf_counter() - last_save >= every_s and not finished(state):
            save(state, chunks)
            last_save = time.perf_counter()
    return "finished", state, chunks


def progress_bar(
    total: int, initial: int, quiet: bool, unit: str = "ep", desc: str = "training"
) -> Any:
    """A tqdm bar on stderr that appears only on runs longer than 2 s."""
    from tqdm.auto import tqdm

    return tqdm(
        total=total,
        initial=initial,
        unit=unit,
        desc=desc,
        disable=quiet,
        delay=2.0,
        file=sys.stderr,
        dynamic_ncols=True,
    )
