"""SPEC invariants over long random rollouts, for parameters drawn by hypothesis.

Every check runs inside the jitted rollout at every step (see
``tests.helpers.invariant_rollout``); parameters are traced, so all examples
share one compiled program.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drqn_jax.env.params import EnvParams
from tests.helpers import invariant_rollout

NUM_ENVS, NUM_STEPS = 8, 1500


@pytest.fixture(scope="module")
def env(env_params):
    return env_params[0]


def _assert_invariants(env, params, seed):
    keys = jax.random.split(jax.random.key(seed), NUM_ENVS)
    checks, count = invariant_rollout(env, params, keys, NUM_STEPS)
    assert np.all(np.asarray(count) == env.static.num_pedestrians)
    failed = {name: int((~np.asarray(ok)).sum()) for name, ok in checks.items()}
    assert not any(failed.values()), failed


def test_invariants_default_params(env):
    _assert_invariants(env, EnvParams(), seed=0)


behaviour_mix = st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0)).filter(
    lambda t: sum(t) > 0.05
)


@settings(
    max_examples=6,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    seed=st.integers(0, 2**31 - 1),
    mix=behaviour_mix,
    speed=st.tuples(st.floats(0.0, 1.5), st.floats(0.0, 1.5)).map(sorted),
    setpoint_mode=st.sampled_from(["measured", "setpoint"]),
    gap_acceptance=st.integers(0, 1),
)
def test_invariants_random_params(env, seed, mix, speed, setpoint_mode, gap_acceptance):
    total = sum(mix)
    p_cross, p_jay = mix[0] / total, mix[1] / total
    params = EnvParams(
        prob_crossing=p_cross,
        prob_jaywalking=p_jay,
        prob_sidewalk=max(0.0, 1.0 - p_cross - p_jay),
        ped_speed_min=speed[0],
        ped_speed_max=speed[1],
        setpoint_mode=setpoint_mode,
        gap_acceptance=gap_acceptance,
    )
    _assert_invariants(env, params, seed)


def test_invariant_checks_can_fail(env):
    """The in-jit checks catch a violation: a speed channel bound far too tight."""
    params = EnvParams(speed_norm_pedestrian=0.01)  # speeds / 0.01 exceed ped_speed_max / 2
    keys = jax.random.split(jax.random.key(1), 2)
    checks, _ = invariant_rollout(env, params, keys, 200)
    assert not np.all(np.asarray(checks["speed_range"]))
