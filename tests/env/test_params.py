"""Environment parameters (drqn_jax/env/params.py): every invalid value is refused
naming its field, and ``EnvParams`` are float32/int32 pytrees that can be swept."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax
from drqn_jax.env.params import EnvParams, StaticEnvParams


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"ped_speed_min": -0.1}, "ped_speed_min"),
        ({"v_ref": -1.0}, "v_ref"),
        ({"v_ref": float("nan")}, "v_ref"),
        ({"prob_crossing": 0.5}, "prob_crossing"),
        ({"prob_sidewalk": 1.5}, "prob_sidewalk"),
        ({"ped_speed_min": 2.0, "ped_speed_max": 1.0}, "ped_speed_min"),
        ({"setpoint_mode": "magic"}, "setpoint_mode"),
        ({"semantic_channel": 7}, "semantic_channel"),
        ({"dt": 0.0}, "dt"),
        ({"gap_acceptance": 0.5}, "gap_acceptance"),
        ({"ped_behaviour_to_car": "wave"}, "ped_behaviour_to_car"),
        ({"collision_model": 2}, "collision_model"),
        ({"reward_ttc_test": 2}, "reward_ttc_test"),
        ({"reward_near_collision_weight": -0.1}, "reward_near_collision_weight"),
        ({"ped_wait_max_s": -1.0}, "ped_wait_max_s"),
        ({"intersection_spacing": 5.0}, r"intersection_spacing = 5: must be >= .* \(13\)"),
        ({"ttc_threshold": 4.0}, "ttc_threshold"),
    ],
)
def test_invalid_params_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        drqn_jax.make(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"num_pedestrians": 0}, "num_pedestrians"),
        ({"num_intersections": -1}, "num_intersections"),
        ({"grid_rows": 2.5}, "grid_rows"),
        ({"max_steps": 0}, "max_steps"),
        ({"ttc_step": 0.0}, "ttc_step"),
    ],
)
def test_invalid_static_params_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        StaticEnvParams(**kwargs)


def test_params_are_float32_pytrees_and_sweepable():
    params = EnvParams()
    leaves = jax.tree.leaves(params)
    assert all(np.asarray(x).dtype in (np.float32, np.int32) for x in leaves)
    # tree operations build params from tracers/ints without re-validating
    axes = jax.tree.map(lambda _: None, params)
    assert isinstance(axes, EnvParams)
    batched = jax.tree.map(lambda x: jnp.stack([x, x]), params)
    assert batched.v_ref.shape == (2,)
