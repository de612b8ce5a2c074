"""``make(env_id)``: the registered environments and their parameter presets."""

import dataclasses
from typing import Any

from drqn_jax.env.params import EnvParams, StaticEnvParams
from drqn_jax.env.urban import UrbanPedestrians

# Each id maps to the StaticEnvParams and EnvParams fields it sets on top of the defaults.
_PRESETS: dict[str, dict[str, Any]] = {
    # The paper's world (SPEC §1-5).
    "UrbanPedestrians-v0": {},
    # The paper's world with pedestrians at realistic walking speeds, 0.5-1.5 m/s.
    "UrbanPedestriansRealistic-v0": {"ped_speed_min": 0.5, "ped_speed_max": 1.5},
    # Pedestrians from the paper's slowest (0.5 km/h) to the realistic fastest (1.5 m/s).
    "UrbanPedestriansMixed-v0": {"ped_speed_max": 1.5},
    # Pedestrians that yield to the car, box-disc contact as the collision test.
    "UrbanPedestriansYielding-v0": {"ped_behaviour_to_car": "yield", "collision_model": "contact"},
    # Pedestrians that ignore the car, box-disc contact (docs/spec.md, "Worlds").
    "UrbanPedestriansHeedless-v0": {"ped_behaviour_to_car": "ignore", "collision_model": "contact"},
    # Each pedestrian drops out of the grid with probability 0.5 per step.
    "UrbanPedestriansOccluded-v0": {"occlusion_prob": 0.5},
    # A map no preset trains on, for agents tested beyond their training.
    "UrbanPedestriansUnseenMap-v0": {
        "num_pedestrians": 15,
        "num_intersections": 4,
        "first_intersection_x": 40.0,
        "intersection_spacing": 40.0,
    },
}


def registered_envs() -> tuple[str, ...]:
    """The ids ``make`` accepts."""
    return tuple(_PRESETS)


def preset(env_id: str) -> dict[str, Any]:
    """The field values ``env_id`` sets on top of the parameter defaults."""
    if env_id not in _PRESETS:
        raise ValueError(f"unknown env id {env_id!r}; registered: {', '.join(_PRESETS)}")
    return dict(_PRESETS[env_id])


def make(
    env_id: str = "UrbanPedestrians-v0", **overrides: Any
) -> tuple[UrbanPedestrians, EnvParams]:
    """``(env, params)`` of a registered id; ``overrides`` set any ``StaticEnvParams``
    (shapes) or ``EnvParams`` field. ValueError: unknown id or field, or out of range."""
    fields = preset(env_id)
    static_names = {f.name for f in dataclasses.fields(StaticEnvParams)}
    traced_names = {f.name for f in dataclasses.fields(EnvParams)}
    for name in overrides:
        if name not in static_names | traced_names:
            raise ValueError(
                f"make({env_id!r}): unknown field {name!r}; fields are those of "
                "StaticEnvParams and EnvParams"
            )
    fields.update(overrides)
    env = UrbanPedestrians(StaticEnvParams(**{n: fields[n] for n in fields if n in static_names}))
    params = env.check_params(EnvParams(**{n: fields[n] for n in fields if n in traced_names}))
    return env, params
