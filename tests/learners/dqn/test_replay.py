"""Episode replay: windows never cross an episode start or read unwritten steps."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from drqn_jax.env.grid import GridInputs
from drqn_jax.env.params import EnvParams, StaticEnvParams
from drqn_jax.learners.dqn.replay import (
    WINDOW_ANYWHERE,
    WINDOW_INSIDE,
    add_transition,
    begin_episodes,
    end_episodes,
    init_replay,
    sample_windows,
)
from drqn_jax.learners.task import observations
from tests.helpers import fast_jit

STATIC = StaticEnvParams(num_pedestrians=2)


def _empty(static: StaticEnvParams) -> GridInputs:
    return GridInputs.empty(static.num_pedestrians)


def _observe(records, last_action):
    return observations(records, last_action, EnvParams(), STATIC)


MAX_LEN, WINDOW, BATCH = 20, 8, 64


def _record(n, episode, t):
    """A GridInputs record whose ``s`` encodes (episode, t) and ``v`` the writer."""
    s = (episode * 1000 + t).astype(jnp.float32)
    zeros = jnp.zeros((n, STATIC.num_pedestrians), jnp.float32)
    return GridInputs(
        s=s,
        v=jnp.arange(n, dtype=jnp.float32),
        position=jnp.stack([zeros - 100.0, zeros], -1),
        velocity=jnp.stack([zeros, zeros], -1),
        heading=zeros,
        speed=zeros,
        visible=zeros > 0,
    )


@fast_jit
def _fill(replay, lengths, episode_ids):
    """Writers play episodes of the given lengths (E, N) one after another; the
    last one is left in progress."""
    n = replay.num_writers

    def episode(replay, inputs):
        length, ids = inputs

        replay = begin_episodes(replay, jnp.ones((n,), bool), _record(n, ids, jnp.zeros(n)))

        def step(replay, t):
            active = t < length
            record = _record(n, ids, jnp.full((n,), t + 1))
            replay = add_transition(
                replay,
                jnp.full((n,), t % 4),
                jnp.full((n,), t, jnp.float32),
                active & (t + 1 == length),
                record,
                active,
            )
            return replay, None

        replay, _ = jax.lax.scan(step, replay, jnp.arange(MAX_LEN))
        return end_episodes(replay, jnp.ones((n,), bool)), None

    replay, _ = jax.lax.scan(episode, replay, (lengths[:-1], episode_ids[:-1]))
    # the last episode: begun, a few steps, not complete
    replay = begin_episodes(
        replay, jnp.ones((n,), bool), _record(n, episode_ids[-1], 0 * lengths[-1])
    )
    return replay


def _sample(replay, key, window_start):  # always traced: one program for both modes
    return sample_windows(replay, key, BATCH, WINDOW, _observe, window_start)


sample = fast_jit(_sample)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(
    writers=st.sampled_from([1, 2, 3]),
    capacity=st.integers(3, 7),
    episodes=st.integers(2, 9),
    lengths=st.lists(st.integers(1, MAX_LEN), min_size=27, max_size=27),
    seed=st.integers(0, 10_000),
    window_start=st.sampled_from([WINDOW_INSIDE, WINDOW_ANYWHERE]),
)
def test_windows_stay_inside_one_complete_episode(
    writers, capacity, episodes, lengths, seed, window_start
):
    capacity = max(capacity, 2 * writers)
    lengths = np.array(lengths[: episodes * writers]).reshape(episodes, writers)
    ids = np.arange(episodes * writers).reshape(episodes, writers) + 1
    replay = _fill(init_replay(capacity, MAX_LEN, writers, _empty(STATIC)), lengths, ids)
    # sampling needs a complete episode (training starts learning only then)
    assume(bool(np.asarray(replay.complete).any()))
    w = sample(replay, jax.random.key(seed), window_start)
    s = np.asarray(w.obs.speed)  # unused here; shape check
    assert s.shape == (WINDOW + 1, BATCH)
    slot = np.asarray(w.slot)
    complete = np.asarray(replay.complete)
    assert complete[slot].all(), "sampled an incomplete (in-progress) slot"
    # decode (episode, t) of every observation in every window from the stored s
    stored_s = np.asarray(replay.records.s)
    start = np.asarray(w.start)
    n = np.asarray(replay.length)[slot]
    mask = np.asarray(w.mask)
    # inside: the window lies in the episode where it can; anywhere: any step
    last = n - 1 if window_start == WINDOW_ANYWHERE else np.maximum(n - WINDOW, 0)
    assert np.all((start >= 0) & (start <= last))
    for b in range(BATCH):
        valid_obs = min(WINDOW, n[b] - start[b]) + 1
        codes = stored_s[slot[b], start[b] : start[b] + valid_obs]
        episode_of = codes // 1000
        t_of = codes % 1000
        assert np.all(episode_of == episode_of[0]), "window crosses an episode start"
        assert np.array_equal(t_of, np.arange(start[b], start[b] + valid_obs))
        assert start[b] + valid_obs - 1 <= n[b], "window reads unwritten steps"
        assert mask[:, b].sum() == valid_obs - 1
        assert np.all(mask[: valid_obs - 1, b]) and not np.any(mask[valid_obs - 1 :, b])
        # each slot's episode was written by the writer that owns the slot
        per_writer = capacity // writers
        assert slot[b] // per_writer < writers
    assert not np.any(np.asarray(w.reward)[~mask]), "padding leaks rewards"
    assert not np.any(np.asarray(w.terminated)[~mask])


BURN_IN = 5


@fast_jit
def _sample_burn_in(replay, key):
    return sample_windows(replay, key, BATCH, WINDOW, _observe, WINDOW_INSIDE, BURN_IN)


def test_burn_in_prepends_the_steps_before_each_window():
    """R2D2's burn-in: the same trained windows as without it (same key), preceded by
    the L steps before their start, masked out of the loss; steps before the
    episode's start are padding and the LSTM restarts at its first observation."""
    lengths = np.array([[12, 7], [20, 3], [15, 9], [4, 4]])
    ids = np.arange(8).reshape(4, 2) + 1
    replay = _fill(init_replay(6, MAX_LEN, 2, _empty(STATIC)), lengths, ids)
    key = jax.random.key(3)
    plain, burnt = sample(replay, key, WINDOW_INSIDE), _sample_burn_in(replay, key)
    np.testing.assert_array_equal(np.asarray(plain.slot), np.asarray(burnt.slot))
    np.testing.assert_array_equal(np.asarray(plain.start), np.asarray(burnt.start))
    for name in ("action", "reward", "terminated", "mask"):
        np.testing.assert_array_equal(
            np.asarray(getattr(burnt, name))[BURN_IN:], np.asarray(getattr(plain, name)), name
        )
    np.testing.assert_array_equal(np.asarray(burnt.obs.grid)[BURN_IN:], np.asarray(plain.obs.grid))
    assert not np.asarray(burnt.mask)[:BURN_IN].any() and not np.asarray(plain.resets).any()
    start = np.asarray(burnt.start)
    t_obs = start[None, :] + np.arange(-BURN_IN, WINDOW + 1)[:, None]
    np.testing.assert_array_equal(np.asarray(burnt.resets), t_obs <= 0)
    # the burn-in observations are the episode's own steps before the window
    stored_s = np.asarray(replay.records.s)
    slot = np.asarray(burnt.slot)
    for b in range(BATCH):
        real = t_obs[:BURN_IN, b] >= 0
        want = stored_s[slot[b], t_obs[:BURN_IN, b][real]]
        np.testing.assert_array_equal(np.asarray(burnt.records.s)[:BURN_IN, b][real], want)
    assert (start < BURN_IN).any() and (start >= BURN_IN).any()  # both kinds were drawn


def test_window_start_anywhere_covers_the_last_steps_as_often_as_the_others():
    """One complete 20-step episode: inside, its last step is in 1 window of every
    13 and a middle step in 8 of 13; anywhere, both are in 8 of every 20."""
    replay = _fill(
        init_replay(2, MAX_LEN, 1, _empty(STATIC)), np.array([[20], [1]]), np.array([[1], [2]])
    )
    for window_start, expected_last, expected_middle in (
        (WINDOW_INSIDE, 1 / 13, 8 / 13),
        (WINDOW_ANYWHERE, 8 / 20, 8 / 20),
    ):
        covered = np.zeros(MAX_LEN)
        for i in range(40):  # 40 × 64 windows
            w = sample(replay, jax.random.key(i), window_start)
            t = np.asarray(w.start)[None, :] + np.arange(WINDOW)[:, None]
            np.add.at(covered, t[np.asarray(w.mask)], 1)
        share = covered / (40 * BATCH)
        assert share[19] == pytest.approx(expected_last, abs=0.03), window_start
        assert share[10] == pytest.approx(expected_middle, abs=0.04), window_start


def test_only_whole_episodes_are_sampled_and_oldest_are_replaced():
    replay = init_replay(2, MAX_LEN, 1, _empty(STATIC))
    lengths = np.array([[5], [6], [7], [3]])
    replay = _fill(replay, lengths, np.array([[1], [2], [3], [4]]))
    # episodes 2 and 3 are complete (1 was replaced by 3); episode 4 is in progress in
    # the slot that held 2, so only episode 3 can be drawn
    assert np.asarray(replay.complete).tolist() == [True, False]
    w = sample(replay, jax.random.key(0), WINDOW_INSIDE)
    codes = np.asarray(replay.records.s)[np.asarray(w.slot), np.asarray(w.start)]
    assert set((codes // 1000).tolist()) == {3}
    assert np.all(np.asarray(replay.length)[np.asarray(w.slot)] == 7)


def test_last_action_and_terminal_flags():
    replay = _fill(
        init_replay(2, MAX_LEN, 1, _empty(STATIC)), np.array([[5], [1]]), np.array([[1], [2]])
    )
    w = sample(replay, jax.random.key(1), WINDOW_INSIDE)
    b = 0
    assert int(w.start[b]) == 0  # 5 < window: the window starts at 0, padded
    # the 6 observations of the 5-step episode; the rest is masked padding
    np.testing.assert_array_equal(np.asarray(w.obs.last_action[:6, b]), [-1, 0, 1, 2, 3, 0])
    np.testing.assert_array_equal(np.asarray(w.action[:5, b]), [0, 1, 2, 3, 0])
    np.testing.assert_array_equal(np.asarray(w.terminated[:, b]), [0, 0, 0, 0, 1, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(w.mask[:, b]), [1, 1, 1, 1, 1, 0, 0, 0])


def test_memory_of_the_paper_replay_fits_target():
    replay = jax.eval_shape(lambda: init_replay(50, 1000, 1, _empty(StaticEnvParams())))
    nbytes = sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(replay))
    assert nbytes <= 32 * 2**20, nbytes


def test_rasterised_observation_equals_the_envs(env_params):
    env, params = env_params
    obs, state = env.reset(jax.random.key(0), params)
    step = jax.jit(env.step_env)
    for t in range(30):
        obs, state, *_ = step(jax.random.key(t), state, 0, params)
    record = GridInputs.of(state.ego, state.pedestrians)
    rebuilt = jax.jit(observations, static_argnums=3)(record, state.last_action, params, env.static)
    assert np.array_equal(np.asarray(rebuilt.grid), np.asarray(obs.grid))
    assert np.array_equal(np.asarray(rebuilt.speed), np.asarray(obs.speed))
