"""The spaces (drqn_jax/env/spaces.py) that ``drqn_jax.testing.check_env_contract``
tests observations with: ``contains`` by hand, and samples inside their space."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.env import spaces
from drqn_jax.env.state import NO_ACTION, NUM_ACTIONS


def test_discrete_contains_start_to_start_plus_n():
    space = spaces.Discrete(NUM_ACTIONS + 1, start=NO_ACTION)  # last_action: -1 … 3
    assert [bool(space.contains(x)) for x in (-2, -1, 0, 3, 4)] == [False, True, True, True, False]
    assert space.shape == ()
    samples = jax.vmap(space.sample)(jax.random.split(jax.random.key(0), 200))
    assert samples.dtype == jnp.int32
    assert set(np.asarray(samples).tolist()) == {-1, 0, 1, 2, 3}


def test_box_contains_its_bounds_and_shape_only():
    space = spaces.Box(np.array([0.0, -1.0]), np.array([1.0, np.inf]), (2,), jnp.float32)
    assert bool(space.contains(jnp.array([0.0, -1.0])))  # the bounds are inside
    assert bool(space.contains(jnp.array([1.0, 1e30])))
    assert not bool(space.contains(jnp.array([1.01, 0.0])))
    assert not bool(space.contains(jnp.array([0.5, -1.5])))
    assert not bool(space.contains(jnp.array([0.5, jnp.nan])))  # NaN is in no interval
    assert not bool(space.contains(jnp.zeros((1, 2))))  # another shape
    assert not bool(spaces.Box(0.0, 1.0, (2,)).contains(jnp.zeros(3)))
    samples = jax.vmap(space.sample)(jax.random.split(jax.random.key(1), 100))
    assert samples.shape == (100, 2) and bool(jnp.all(jax.vmap(space.contains)(samples)))


def test_dict_contains_every_entry(env_params):
    env, params = env_params
    space = env.observation_space(params)
    obs, _ = env.reset(jax.random.key(0), params)
    assert bool(space.contains(obs))  # an Observation: entries read as attributes
    as_dict = {"grid": obs.grid, "speed": obs.speed, "last_action": obs.last_action}
    assert bool(space.contains(as_dict))
    assert not bool(space.contains(dict(as_dict, speed=jnp.float32(-0.1))))
    assert not bool(space.contains(dict(as_dict, last_action=jnp.int32(4))))
    assert not bool(space.contains(dict(as_dict, grid=obs.grid.at[0, 0, 1].set(1.5))))
    assert bool(space.contains(space.sample(jax.random.key(2))))
