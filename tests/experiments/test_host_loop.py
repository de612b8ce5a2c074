"""The one host loop of training (drqn_jax/experiments/host_loop.py)."""

from __future__ import annotations

import math
import os
import signal

import pytest

from drqn_jax.experiments.host_loop import StopRequest, run_chunks


def loop(stop=None, *, healthy=None, every_s=math.inf, start=0, end=5):
    """run_chunks over an integer state that a chunk advances by one."""
    saves, seen = [], []
    status, state, chunks = run_chunks(
        lambda n: n + 1,
        start,
        finished=lambda n: n >= end,
        stop=StopRequest() if stop is None else stop,
        save=lambda n, c: saves.append((n, c)),
        every_s=every_s,
        healthy=healthy,
        on_chunk=seen.append,
        chunks=start,
    )
    return status, state, chunks, saves, seen


def test_runs_chunks_until_finished_and_reports_each():
    status, state, chunks, saves, seen = loop()
    assert (status, state, chunks) == ("finished", 5, 5)
    assert seen == [1, 2, 3, 4, 5] and saves == []


def test_a_resumed_run_counts_on_and_a_finished_one_runs_nothing():
    assert loop(start=3)[:3] == ("finished", 5, 5)
    assert loop(start=5)[:3] == ("finished", 5, 5) and loop(start=5)[4] == []


def test_saves_between_chunks_never_after_the_last():
    *_, saves, _ = loop(every_s=0.0)
    assert saves == [(1, 1), (2, 2), (3, 3), (4, 4)]


def test_an_unhealthy_chunk_is_dropped_and_ends_the_loop():
    status, state, chunks, _, seen = loop(healthy=lambda n: n < 3)
    assert (status, state, chunks) == ("diverged", 2, 2) and seen == [1, 2]


def test_a_signal_stops_before_the_next_chunk():
    stop = StopRequest()

    def chunk(n):
        if n == 2:
            os.kill(os.getpid(), signal.SIGTERM)  # arrives while the chunk runs
        return n + 1

    with stop.installed():
        status, state, chunks = run_chunks(
            chunk,
            0,
            finished=lambda n: n >= 5,
            stop=stop,
            save=lambda n, c: None,
            every_s=math.inf,
        )
    assert (status, state, chunks) == ("interrupted", 3, 3)
    assert stop.signal == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is not stop._handler  # the old handler is back


def test_a_second_signal_aborts():
    stop = StopRequest()
    with stop.installed(), pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)
