"""Replay of whole episodes (paper Table II: M = 50; SPEC §7).

Per observation the replay stores a *record*, any pytree the environment's
task chooses (:mod:`drqn_jax.learners.task`), and turns records into the network's
observations at sample time with the task's ``observe``. For the paper's env
the record is compact: a :class:`~drqn_jax.env.grid.GridInputs` (6P + 2
floats) instead of the 45×30×4 grid, re-rasterised at sample time, the speed
and last-action inputs rebuilt from the record and the stored actions (about
13 MB for M = 50 episodes of up to 1000 steps with P = 10); for a flat-vector
env it is the observation itself. Per transition the replay stores the
action, reward and ``terminated`` flag.

The ring holds M episode slots. With N parallel environments each writes its
episodes, oldest first, into its own ``M // N`` slots, so two writers never
share a slot. A slot can be sampled only once its episode is complete; a
slot being rewritten is not sampled. A sample draws ``batch`` complete
episodes uniformly with replacement and from each a window of ``window``
consecutive transitions (``window + 1`` observations) at a uniform start
(the capacity must be at least 2N, so that every writer has a complete
episode while it fills the next);
episodes shorter than the window are padded and masked. A window therefore
never crosses an episode start and never reads an unwritten step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.env.state import NO_ACTION
from drqn_jax.learners.hyperparams import WINDOW_STARTS
from drqn_jax.pytree import pytree_dataclass

#: ``observe(records, last_action) -> observations``: the network's inputs of
#: records with leaves (T, B, …) and the actions before them (T, B) int32.
Observe = Callable[[Any, jax.Array], Any]

__all__ = [
    "EpisodeReplay",
    "Windows",
    "add_transition",
    "begin_episodes",
    "end_episodes",
    "init_replay",
    "replay_bytes",
    "sample_windows",
]

#: ``Hyperparams.window_start`` of a window inside the episode, and anywhere in it.
WINDOW_INSIDE, WINDOW_ANYWHERE = WINDOW_STARTS.index("inside"), WINDOW_STARTS.index("anywhere")


@pytree_dataclass
class EpisodeReplay:
    """Ring of M episode slots of up to L transitions, written by N environments.

    Attributes:
        records: the task's records with leaves (M, L + 1, …): the observations.
        action: (M, L) int32; reward: (M, L) float32; terminated: (M, L) bool.
        length: (M,) int32, transitions stored in each slot.
        complete: (M,) bool, the slot holds a whole episode (may be sampled).
        slot: (N,) int32, the slot each environment is writing.
        episodes: (N,) int32, episodes each environment has begun.
        carry: with a stored state (R2D2's), the acting network's recurrent
            state as it entered each observation, leaves (M, L + 1, …); else None.
    """

    records: Any
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    length: jax.Array
    complete: jax.Array
    slot: jax.Array
    episodes: jax.Array
    carry: Any = None

    @property
    def capacity(self) -> int:
        return self.length.shape[0]

    @property
    def max_length(self) -> int:
        return self.action.shape[1]

    @property
    def num_writers(self) -> int:
        return self.slot.shape[0]


@pytree_dataclass
class Windows:
    """A sampled minibatch, time-major.

    Attributes:
        obs: the network's observations, leaves (W + 1, B, …) (rasterised
            grids for the paper's env).
        records: the records with leaves (W + 1, B, …) that ``obs`` was made
            from (for the paper's env the true state's ego and pedestrians).
        action, reward, terminated, mask: (W, B); ``mask`` is false on padding
            and on the burn-in steps.
        slot, start: (B,) int32, where each window came from (``start``: its first
            trained step).
        resets: (W + 1, B) bool, where the LSTM starts afresh: at the episode's
            first observation and before it, inside a burn-in reaching past the
            episode's start (all false without burn-in: the carry starts at zero).
        carry: with a stored state, the recurrent state (leaves (B, …)) the acting
            network entered each window's first observation with; else None
            (the window's LSTM starts from zeros).
    """

    obs: Any
    records: Any
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    mask: jax.Array
    slot: jax.Array
    start: jax.Array
    resets: jax.Array
    carry: Any = None


def init_replay(
    capacity: int, max_length: int, num_writers: int, record: Any, carry: Any = None
) -> EpisodeReplay:
    """An empty replay of ``capacity`` episodes of up to ``max_length`` transitions
    whose observations are stored as pytrees shaped like ``record`` (one step's),
    with the recurrent state shaped like ``carry`` (one env's) beside each when
    given (R2D2's stored state)."""
    if num_writers < 1 or capacity < 2 * num_writers:
        raise ValueError(
            f"replay capacity = {capacity} episodes: must be >= 2 × the number of parallel "
            f"environments ({num_writers}); each writes its own slots and needs one to fill "
            "while another holds a complete episode"
        )
    m, n_obs = capacity, max_length + 1

    def buffer(example: Any) -> Any:
        return jax.tree.map(lambda x: jnp.zeros((m, n_obs, *jnp.shape(x)), x.dtype), example)

    return EpisodeReplay(
        records=buffer(record),
        carry=None if carry is None else buffer(carry),
        action=jnp.zeros((m, max_length), jnp.int32),
        reward=jnp.zeros((m, max_length), jnp.float32),
        terminated=jnp.zeros((m, max_length), bool),
        length=jnp.zeros((m,), jnp.int32),
        complete=jnp.zeros((m,), bool),
        slot=jnp.zeros((num_writers,), jnp.int32),
        episodes=jnp.zeros((num_writers,), jnp.int32),
    )


def replay_bytes(replay: EpisodeReplay) -> int:
    """Bytes held by the replay's arrays."""
    return sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(replay))


def _set(buffer: jax.Array, where: jax.Array, index: tuple, value: jax.Array) -> jax.Array:
    """``buffer.at[index].set(value)`` only for writers where ``where`` (N,) is true.

    Skipped writers get an out-of-range slot and the scatter drops them, so
    the buffer is only written, never read: XLA then updates it in place
    instead of copying it.
    """
    slot = jnp.where(where, index[0], buffer.shape[0])
    return buffer.at[(slot, *index[1:])].set(value, mode="drop", unique_indices=True)


def begin_episodes(
    replay: EpisodeReplay, starting: jax.Array, first: Any, first_carry: Any = None
) -> EpisodeReplay:
    """Writers flagged in ``starting`` (N,) start an episode with observation ``first``
    (and, with a stored state, the recurrent state ``first_carry`` it is seen with).

    Each takes the oldest of its own slots, which stops being sampleable.
    """
    n = replay.num_writers
    per_writer = replay.capacity // n
    writer = jnp.arange(n, dtype=jnp.int32)
    slot = jnp.where(starting, writer * per_writer + replay.episodes % per_writer, replay.slot)
    zero = jnp.zeros((n,), jnp.int32)
    records = jax.tree.map(
        lambda buf, x: _set(buf, starting, (slot, zero), x), replay.records, first
    )
    if replay.carry is not None:
        carry = jax.tree.map(
            lambda buf, x: _set(buf, starting, (slot, zero), x), replay.carry, first_carry
        )
        replay = replay.replace(carry=carry)
    return replay.replace(
        records=records,
        length=_set(replay.length, starting, (slot,), zero),
        complete=_set(replay.complete, starting, (slot,), jnp.zeros((n,), bool)),
        slot=slot,
        episodes=replay.episodes + starting.astype(jnp.int32),
    )


def add_transition(
    replay: EpisodeReplay,
    action: jax.Array,
    reward: jax.Array,
    terminated: jax.Array,
    next_record: Any,
    active: jax.Array | None = None,
    next_carry: Any = None,
) -> EpisodeReplay:
    """Append one transition per writer (N,) to its current episode.

    ``next_record`` is the observation after the action (the pre-reset one
    when the episode ended), ``next_carry`` (with a stored state) the recurrent
    state the acting network holds for it. Writers where ``active`` is false
    are skipped. Past ``max_length`` transitions nothing more is stored.
    """
    n = replay.num_writers
    active = jnp.ones((n,), bool) if active is None else active
    t = replay.length[replay.slot]
    active = active & (t < replay.max_length)
    t = jnp.minimum(t, replay.max_length - 1)
    slot = replay.slot
    records = jax.tree.map(
        lambda buf, x: _set(buf, active, (slot, t + 1), x), replay.records, next_record
    )
    if replay.carry is not None:
        carry = jax.tree.map(
            lambda buf, x: _set(buf, active, (slot, t + 1), x), replay.carry, next_carry
        )
        replay = replay.replace(carry=carry)
    return replay.replace(
        records=records,
        action=_set(replay.action, active, (slot, t), action.astype(jnp.int32)),
        reward=_set(replay.reward, active, (slot, t), reward.astype(jnp.float32)),
        terminated=_set(replay.terminated, active, (slot, t), terminated),
        length=_set(replay.length, active, (slot,), t + 1),
    )


def end_episodes(replay: EpisodeReplay, ending: jax.Array) -> EpisodeReplay:
    """Mark the current episode of writers flagged in ``ending`` (N,) complete."""
    ones = jnp.ones((replay.num_writers,), bool)
    return replay.replace(complete=_set(replay.complete, ending, (replay.slot,), ones))


def sample_windows(
    replay: EpisodeReplay,
    key: jax.Array,
    batch: int,
    window: int,
    observe: Observe,
    window_start: int | jax.Array = WINDOW_INSIDE,
    burn_in: int = 0,
) -> Windows:
    """Draw ``batch`` windows of ``window`` transitions from complete episodes.

    Episodes are drawn uniformly with replacement among complete slots (call
    only once one is complete). The start is uniform in ``[0, max(n − W, 0)]``
    with ``window_start = WINDOW_INSIDE`` (SPEC §7: windows lie inside the
    episode, so its last W − 1 steps are in fewer windows than the others, its
    last step in 1 of every n − W + 1), or in ``[0, n − 1]`` with
    ``WINDOW_ANYWHERE`` (windows run into masked padding past the episode's end,
    and every step from the W-th on is in W of every n).

    With ``burn_in`` = L > 0 (static; R2D2's burn-in) each window is preceded by
    the L steps before its start, which only warm the LSTM: the returned windows
    have L + W transitions, the first L masked out of the loss; steps before the
    episode's start are padding, and the LSTM restarts at its first observation
    (``resets``). The trained steps are those of ``burn_in = 0``'s windows.

    ``observe`` turns the windows' records into the network's observations
    (:func:`~drqn_jax.learners.task.observations` with the env's parameters for the
    paper's env). With a stored state the windows carry the recurrent state the
    acting network entered their first observation with (burn-in included).
    """
    key_slot, key_start = jax.random.split(key)
    logits = jnp.where(replay.complete, 0.0, -jnp.inf)
    slot = jax.random.categorical(key_slot, logits, shape=(batch,)).astype(jnp.int32)
    n = replay.length[slot]
    last = jnp.where(window_start == WINDOW_ANYWHERE, n - 1, jnp.maximum(n - window, 0))
    start = jax.random.randint(key_start, (batch,), 0, last + 1)
    offsets = jnp.arange(-burn_in, window, dtype=jnp.int32)[:, None]  # (L + W, 1)
    t = start[None, :] + offsets  # (L + W, B)
    mask = (offsets >= 0) & (t < n[None, :])
    t_obs = jnp.concatenate([t, t[-1:] + 1], axis=0)  # (L + W + 1, B)
    resets = t_obs <= 0 if burn_in else jnp.zeros(t_obs.shape, bool)
    t_obs = jnp.clip(t_obs, 0, replay.max_length)
    t = jnp.clip(t, 0, replay.max_length - 1)
    records = jax.tree.map(lambda buf: buf[slot[None, :], t_obs], replay.records)
    prev = jnp.maximum(t_obs - 1, 0)
    last_action = jnp.where(t_obs == 0, NO_ACTION, replay.action[slot[None, :], prev])
    return Windows(
        obs=observe(records, last_action),
        records=records,
        action=replay.action[slot[None, :], t],
        reward=jnp.where(mask, replay.reward[slot[None, :], t], 0.0),
        terminated=replay.terminated[slot[None, :], t] & mask,
        mask=mask,
        slot=slot,
        start=start,
        resets=resets,
        carry=None
        if replay.carry is None
        else jax.tree.map(lambda buf: buf[slot, t_obs[0]], replay.carry),
    )
