"""Environment state and observation pytrees (SPEC §2–4).

Shapes use P = ``StaticEnvParams.num_pedestrians``, W = ``NUM_WAYPOINTS``,
K = ``StaticEnvParams.pid_window``. All leaves of a single environment are
unbatched; ``vmap`` adds a leading batch axis to every leaf.
"""

from __future__ import annotations

import jax

from drqn_jax.pytree import pytree_dataclass

NUM_WAYPOINTS = 3  # every pedestrian path is padded to this many waypoints

# Behaviours (SPEC §3), in the order of their probabilities in EnvParams.
CROSSING, JAYWALKING, SIDEWALK = 0, 1, 2
BEHAVIOURS = ("crossing", "jaywalking", "sidewalk")

# Actions (paper §IV-B, Algorithm 1), Discrete(4) in this order.
ACCELERATE, SLOW_DOWN, BRAKE, STEER = 0, 1, 2, 3
ACTIONS = ("accelerate", "slow_down", "brake", "steer")
NUM_ACTIONS = 4
NO_ACTION = -1  # ``last_action`` at episode start (its one-hot is all zeros)

__all__ = [
    "ACTIONS",
    "BEHAVIOURS",
    "EgoState",
    "EnvState",
    "Observation",
    "PedestrianState",
]


@pytree_dataclass
class EgoState:
    """The ego vehicle on its route (SPEC §2).

    Attributes:
        s: () float32, arc length of the box centre along the route (m); the
            pose is ``(s, -lane_width / 2)`` heading +x.
        v: () float32, speed (m/s), never negative.
        accel: () float32, actual (lagged) acceleration (m/s^2).
        v_setpoint: () float32, the PID's desired speed v_d (m/s).
        pid_errors: (K,) float32, last K speed errors (km/h), newest last.
        pid_count: () int32, how many of ``pid_errors`` are filled (<= K).
    """

    s: jax.Array
    v: jax.Array
    accel: jax.Array
    v_setpoint: jax.Array
    pid_errors: jax.Array
    pid_count: jax.Array


@pytree_dataclass
class PedestrianState:
    """The P pedestrians (SPEC §3).

    Attributes:
        position: (P, 2) float32, centres (m).
        velocity: (P, 2) float32, displacement of the last step / dt (m/s).
        speed: (P,) float32, distance walked in the last step / dt (m/s): the
            norm of ``velocity``, computed once where the step knows it.
        heading: (P,) float32, walking direction (rad), kept while standing.
        desired_speed: (P,) float32 (m/s).
        behaviour: (P,) int32, CROSSING | JAYWALKING | SIDEWALK.
        waypoints: (P, W, 2) float32, the path computed at spawn.
        waypoint_index: (P,) int32, next waypoint; ``W`` means done.
        waited: (P,) float32, seconds the pedestrian has stood yielding to the car
            (``ped_behaviour_to_car = "yield"``); once it reaches
            ``EnvParams.ped_wait_max_s`` the pedestrian walks on (SPEC §3).
        visible: (P,) bool, in the observation grid this step: each pedestrian is
            left out with probability ``EnvParams.occlusion_prob`` per step
            (partial observability; all visible by default, as in the paper).
            Only the observation depends on it: collisions, TTC and the
            rule-based agent see every pedestrian.
    """

    position: jax.Array
    velocity: jax.Array
    speed: jax.Array
    heading: jax.Array
    desired_speed: jax.Array
    behaviour: jax.Array
    waypoints: jax.Array
    waypoint_index: jax.Array
    waited: jax.Array
    visible: jax.Array

    @property
    def done(self) -> jax.Array:
        """(P,) bool: the pedestrian walked its whole path."""
        return self.waypoint_index >= self.waypoints.shape[-2]


@pytree_dataclass
class EnvState:
    """Full simulator state of one environment.

    Attributes:
        ego: the ego vehicle.
        pedestrians: the P pedestrians.
        last_action: () int32, previous action, ``NO_ACTION`` (-1) at reset.
        time: () int32, decision steps taken in this episode.
    """

    ego: EgoState
    pedestrians: PedestrianState
    last_action: jax.Array
    time: jax.Array


@pytree_dataclass
class Observation:
    """What the agent sees (paper §IV-B "State space", §V-A).

    Attributes:
        grid: (rows, cols, 4) float32, ego-centred grid, channels occupancy,
            relative heading / pi, speed / norm, semantics / 3.
        speed: () float32, ego speed / v_ref.
        last_action: () int32, previous action, -1 at episode start.
    """

    grid: jax.Array
    speed: jax.Array
    last_action: jax.Array
