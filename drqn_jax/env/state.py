"""Environment state and observation pytrees of one env (SPEC §2–4).
P = ``num_pedestrians``, W = ``NUM_WAYPOINTS``, K = ``pid_window``."""

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


@pytree_dataclass
class EgoState:
    """The ego vehicle on its route (SPEC §2); pose ``(s, -lane_width / 2)`` heading +x."""

    s: jax.Array  # () float32, arc length of the box centre (m)
    v: jax.Array  # () float32, speed (m/s) >= 0
    accel: jax.Array  # () float32, lagged acceleration (m/s^2)
    v_setpoint: jax.Array  # () float32, the PID's v_d (m/s)
    pid_errors: jax.Array  # (K,) float32, last speed errors (km/h), newest last
    pid_count: jax.Array  # () int32, filled entries of pid_errors


@pytree_dataclass
class PedestrianState:
    """The P pedestrians (SPEC §3)."""

    position: jax.Array  # (P, 2) float32, centres (m)
    velocity: jax.Array  # (P, 2) float32, last step's displacement / dt (m/s)
    speed: jax.Array  # (P,) float32, the norm of velocity
    heading: jax.Array  # (P,) float32 (rad), kept while standing
    desired_speed: jax.Array  # (P,) float32 (m/s)
    behaviour: jax.Array  # (P,) int32, CROSSING | JAYWALKING | SIDEWALK
    waypoints: jax.Array  # (P, W, 2) float32, the path drawn at spawn
    waypoint_index: jax.Array  # (P,) int32, next waypoint; W: done
    waited: jax.Array  # (P,) float32, seconds stood yielding to the car
    visible: jax.Array  # (P,) bool, in the grid this step (only the grid reads it)

    @property
    def done(self) -> jax.Array:
        """(P,) bool: the pedestrian walked its whole path."""
        return self.waypoint_index >= self.waypoints.shape[-2]


@pytree_dataclass
class EnvState:
    """Full simulator state of one environment."""

    ego: EgoState
    pedestrians: PedestrianState
    last_action: jax.Array  # () int32, NO_ACTION at reset
    time: jax.Array  # () int32, decision steps in this episode


@pytree_dataclass
class Observation:
    """What the agent sees (paper §IV-B "State space", §V-A; SPEC §4)."""

    grid: jax.Array  # (rows, cols, 4) float32 (drqn_jax.env.grid)
    speed: jax.Array  # () float32, ego speed / v_ref
    last_action: jax.Array  # () int32, NO_ACTION at episode start
