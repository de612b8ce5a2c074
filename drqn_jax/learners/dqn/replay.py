"""Replay of whole episodes (paper §V-B, Table II: M = 50; SPEC §7): per observation the
task's *record* (the paper's env: ``GridInputs``, rasterised at sample time), per transition
action, reward, ``terminated``. Each of N writers fills its own ``M // N`` slots, oldest
first; complete episodes are sampled in windows that never cross an episode start."""

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from drqn_jax.env.state import NO_ACTION
from drqn_jax.learners.hyperparams import WINDOW_STARTS
from drqn_jax.pytree import pytree_dataclass

#: ``Hyperparams.window_start`` of a window inside the episode, and anywhere in it.
WINDOW_INSIDE, WINDOW_ANYWHERE = WINDOW_STARTS.index("inside"), WINDOW_STARTS.index("anywhere")


@pytree_dataclass
class EpisodeReplay:
    """Ring of M episode slots of up to L transitions written by N envs: ``records`` (M, L + 1,
    …); ``action``/``reward``/``terminated`` (M, L); ``length``, ``complete`` (M,); ``slot``,
    ``episodes`` (N,); ``carry``: R2D2's stored recurrent state (M, L + 1, …) or None."""

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
    def max_length(self) -> int:
        return self.action.shape[1]

    @property
    def num_writers(self) -> int:
        return self.slot.shape[0]


@pytree_dataclass
class Windows:
    """A sampled minibatch, time-major: ``obs``, ``records`` (W + 1, B, …), ``resets`` (W + 1, B)
    LSTM restarts (burn-in past the episode start); ``action``/``reward``/``terminated``/``mask``
    (W, B), mask false on padding and burn-in; ``slot``/``start`` (B,); ``carry`` (B, …) or None."""

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
    """An empty replay of ``capacity`` episodes of up to ``max_length`` transitions,
    records shaped like ``record`` (and stored states like ``carry`` when given);
    ``capacity`` >= 2 × ``num_writers`` (``TrainConfig.replay_episodes`` says it)."""
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


def _set(buffer: jax.Array, where: jax.Array, index: tuple, value: jax.Array) -> jax.Array:
    """``buffer.at[index].set(value)`` for writers where ``where`` (N,); others get an
    out-of-range slot and are dropped, so XLA updates the buffer in place."""
    slot = jnp.where(where, index[0], buffer.shape[0])
    return buffer.at[(slot, *index[1:])].set(value, mode="drop", unique_indices=True)


def _write(
    replay: EpisodeReplay, where: jax.Array, index: tuple, record: Any, carry: Any
) -> EpisodeReplay:
    """``replay`` with ``record`` (and ``carry`` where states are stored) at ``index``
    for writers where ``where`` (N,)."""

    def write(buf: jax.Array, x: jax.Array) -> jax.Array:
        return _set(buf, where, index, x)

    carry = None if replay.carry is None else jax.tree.map(write, replay.carry, carry)
    return replay.replace(records=jax.tree.map(write, replay.records, record), carry=carry)


def begin_episodes(
    replay: EpisodeReplay, starting: jax.Array, first: Any, first_carry: Any = None
) -> EpisodeReplay:
    """Writers flagged in ``starting`` (N,) start an episode at ``first`` (and
    ``first_carry``) in the oldest of their slots, which stops being sampleable."""
    n = replay.num_writers
    per_writer = replay.length.shape[0] // n  # M // N slots
    writer = jnp.arange(n, dtype=jnp.int32)
    slot = jnp.where(starting, writer * per_writer + replay.episodes % per_writer, replay.slot)
    zero = jnp.zeros((n,), jnp.int32)
    return _write(replay, starting, (slot, zero), first, first_carry).replace(
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
    active: jax.Array,
    next_carry: Any = None,
) -> EpisodeReplay:
    """Append one transition per writer (N,) where ``active``; ``next_record`` is the
    pre-reset observation after the action. Nothing is stored past ``max_length``."""
    t = replay.length[replay.slot]
    active = active & (t < replay.max_length)
    t = jnp.minimum(t, replay.max_length - 1)
    slot = replay.slot
    return _write(replay, active, (slot, t + 1), next_record, next_carry).replace(
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
    observe: Callable[[Any, jax.Array], Any],
    window_start: int | jax.Array = WINDOW_INSIDE,
    burn_in: int = 0,
) -> Windows:
    """``batch`` windows of ``window`` transitions from complete episodes (uniform, with
    replacement), observed by ``observe(records (T, B, …), last actions (T, B))``; the start
    uniform in ``[0, max(n − W, 0)]`` (``WINDOW_INSIDE``, SPEC §7) or ``[0, n − 1]``
    (``WINDOW_ANYWHERE``); ``burn_in`` = L prepends L masked steps (R2D2)."""
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
