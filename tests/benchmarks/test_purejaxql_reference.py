"""``benchmarks/purejaxql_reference.py``'s adapters: the gymnax step purejaxql was
written for, and the LSTM that stands in for its GRU (its clone is not needed).
gymnax is imported where it is used, not at collection: importing it (and the
plotting libraries it brings) costs each pytest worker about 2 s."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks.purejaxql_reference import _gymnax_step_of_its_time, lstm_core


def test_the_step_is_gymnaxs_five_tuple_with_done_as_terminated_or_truncated():
    import gymnax
    from gymnax.wrappers.purerl import FlattenObservationWrapper, LogWrapper

    env, params = gymnax.make("MemoryChain-bsuite")
    env = LogWrapper(FlattenObservationWrapper(env))
    six = LogWrapper.step
    try:
        _gymnax_step_of_its_time()
        _gymnax_step_of_its_time()  # once only: not wrapped twice
        key = jax.random.key(0)
        _, state = env.reset(key, params)
        want = six(env, key, state, 0, params)
        obs, _, reward, done, info = env.step(key, state, 0, params)
        np.testing.assert_array_equal(obs, want[0])
        assert float(reward) == float(want[2])
        assert bool(done) == bool(want[3] | want[4])
        assert "final_observation" not in info and "returned_episode_returns" in info
    finally:
        LogWrapper.step = six


def test_the_lstm_core_resets_its_carry_where_an_episode_starts():
    core = lstm_core()
    carry = core.initialize_carry(4, 3)  # width 4, batch 3: [c, h] in one array
    assert carry.shape == (3, 8)
    ins = jnp.ones((5, 3, 2))  # (time, batch, features)
    resets = jnp.zeros((5, 3), bool).at[3, 1].set(True)
    params = core().init(jax.random.key(0), carry, (ins, resets))
    last, ys = core().apply(params, carry, (ins, resets))
    assert ys.shape == (5, 3, 4) and last.shape == (3, 8)
    # batch 1 restarts at step 3: its outputs there repeat those of step 0
    np.testing.assert_allclose(ys[3, 1], ys[0, 1], rtol=1e-6)
    assert not np.allclose(ys[3, 0], ys[0, 0])
