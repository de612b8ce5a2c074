"""The registered ids (drqn_jax/registry.py): ``make(id, **overrides)`` builds each
world's env and parameters, and refuses unknown ids and fields."""

from __future__ import annotations

import jax
import pytest

import drqn_jax


def test_registered_ids_and_overrides():
    assert set(drqn_jax.registered_envs()) >= {
        "UrbanPedestrians-v0",
        "UrbanPedestriansRealistic-v0",
        "UrbanPedestriansHeedless-v0",
        "UrbanPedestriansMixed-v0",
        "UrbanPedestriansYielding-v0",
        "UrbanPedestriansOccluded-v0",
        "UrbanPedestriansUnseenMap-v0",
    }
    unseen, unseen_params = drqn_jax.make("UrbanPedestriansUnseenMap-v0")
    assert unseen.static.num_pedestrians == 15 and unseen.static.num_intersections == 4
    assert float(unseen_params.intersection_spacing) == 40.0
    assert float(drqn_jax.make("UrbanPedestriansOccluded-v0")[1].occlusion_prob) == 0.5
    _, realistic = drqn_jax.make("UrbanPedestriansRealistic-v0")
    assert float(realistic.ped_speed_min) == 0.5 and float(realistic.ped_speed_max) == 1.5
    _, mixed = drqn_jax.make("UrbanPedestriansMixed-v0")
    paper = drqn_jax.make()[1]
    assert (
        float(mixed.ped_speed_min) == float(paper.ped_speed_min)
        and float(mixed.ped_speed_max) == 1.5
    )
    _, heedless = drqn_jax.make("UrbanPedestriansHeedless-v0")
    assert int(heedless.ped_behaviour_to_car) == int(paper.ped_behaviour_to_car) == 0  # ignore
    assert int(heedless.collision_model) == 0 and int(paper.collision_model) == 1  # contact
    env, params = drqn_jax.make(num_pedestrians=4, v_ref=5.0, semantic_channel="map")
    assert env.static.num_pedestrians == 4 and float(params.v_ref) == 5.0
    obs, state = env.reset(jax.random.key(0), params)
    assert state.pedestrians.position.shape == (4, 2)
    assert float(obs.grid[..., 3].max()) == 1.0  # the dense map shows road cells
    with pytest.raises(ValueError, match="unknown env id"):
        drqn_jax.make("CartPole-v1")
    with pytest.raises(ValueError, match="'pedestrian_count'"):
        drqn_jax.make(pedestrian_count=3)
