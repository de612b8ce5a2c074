"""The one host loop of training (``train`` and sweeps): between compiled chunks, check for a stop
request or non-finite loss, show progress and checkpoint; what differs comes in as functions."""

import contextlib
import signal
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

import jax
import jax.numpy as jnp

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
    def installed(self) -> Iterator["StopRequest"]:
        """Catch SIGINT and SIGTERM while the block runs; the old handlers return after."""
        previous = {s: signal.signal(s, self._handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for s, handler in previous.items():
                signal.signal(s, handler)


@jax.jit
def finite_training(state: Any) -> jax.Array:
    """() bool: the state's online parameters and losses are all finite."""
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
    """Run chunks until the state is ``finished``, ``stop`` is set or it turns unhealthy;
    ``save(state, chunks)`` runs every ``every_s`` s between chunks (not after the last). Returns
    ``(status, state, chunks)``: ``"finished"``, ``"interrupted"`` or ``"diverged"`` (``state`` then
    the last healthy one)."""
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
