"""Environment parameters (SPEC §1–6): static (hashable, a ``jit`` static argument) and
traced (scalars: ``vmap`` over ``EnvParams`` sweeps them), validated on construction. SI
units; the PID's error is in km/h as in CARLA's local planner."""

import dataclasses
import math

import numpy as np

from drqn_jax.pytree import (
    check_counts,
    check_order,
    check_sums_to_one,
    is_concrete,
    param,
    pytree_dataclass,
    show_value,
    validate,
)

KMH = 1.0 / 3.6  # one km/h in m/s

# Switch codes (the values stored in EnvParams' switch fields).
SETPOINT_MODES = ("measured", "setpoint")
SPEED_CHANNELS = ("pedestrian", "relative")
SEMANTIC_CHANNELS = ("pedestrian", "map", "threat")
PED_BEHAVIOURS_TO_CAR = ("ignore", "yield")
COLLISION_MODELS = ("contact", "authors")
TTC_TESTS = ("contact", "collision")
SETPOINT_CHANGES = ("decision", "tick")
SETPOINT_MEASURED, SETPOINT_PREVIOUS = 0, 1
SPEED_PEDESTRIAN, SPEED_RELATIVE = 0, 1
SEMANTIC_PEDESTRIAN, SEMANTIC_MAP, SEMANTIC_THREAT = 0, 1, 2
PED_IGNORE, PED_YIELD = 0, 1
COLLISION_CONTACT, COLLISION_AUTHORS = 0, 1
TTC_CONTACT, TTC_COLLISION = 0, 1
CHANGE_PER_DECISION, CHANGE_PER_TICK = 0, 1


@dataclasses.dataclass(frozen=True)
class StaticEnvParams:
    """Shape-setting settings (hashable; a change recompiles)."""

    num_pedestrians: int = 10  # P, alive at all times (paper §V-D)
    num_intersections: int = 3  # along the route (SPEC §1)
    grid_rows: int = 45  # cells along the ego's axis (paper §V-A)
    grid_cols: int = 30  # cells across
    cell_size: float = 1.0  # m
    grid_x_min: float = -5.0  # m, row 0's near edge from the ego centre
    grid_y_min: float = -15.0  # m, column 0's right edge from the ego centre
    max_steps: int = 1000  # ticks of dt before truncation (paper's S)
    decision_steps: int = 1  # k: ticks one action holds (1: the paper's 0.1 s; SPEC §2)
    ttc_horizon: float = 3.0  # s; TTC samples at 0, ttc_step, …, ttc_horizon
    ttc_step: float = 0.1  # s
    pid_window: int = 10  # past errors in the PID integral (CARLA)

    def __post_init__(self) -> None:
        counts = ("num_pedestrians", "num_intersections", "grid_rows", "grid_cols")
        check_counts(self, (*counts, "max_steps", "decision_steps", "pid_window"))
        for name in ("cell_size", "ttc_horizon", "ttc_step", "grid_x_min", "grid_y_min"):
            value, rule = getattr(self, name), "" if name.startswith("grid_") else " > 0"
            number = isinstance(value, int | float) and math.isfinite(value)
            if not number or (rule and value <= 0):
                raise ValueError(
                    f"StaticEnvParams.{name} = {value!r}: must be a finite number{rule}"
                )
        if self.ttc_step > self.ttc_horizon:
            raise ValueError(
                f"StaticEnvParams.ttc_step = {self.ttc_step!r}: must be <= ttc_horizon "
                f"({self.ttc_horizon!r})"
            )

    @property
    def ttc_samples(self) -> int:
        """TTC sample times, ``0 … ttc_horizon`` inclusive (31 by default)."""
        return round(self.ttc_horizon / self.ttc_step) + 1

    @property
    def grid_shape(self) -> tuple[int, int, int]:
        """``(rows, cols, 4)``: the observation grid's shape."""
        return (self.grid_rows, self.grid_cols, 4)


@pytree_dataclass
class EnvParams:
    """Traced parameters (SPEC §1–6): scalars, or arrays with a leading batch axis for a
    sweep; switches take their names and are stored as ``int`` codes."""

    # --- Map (SPEC §1) -------------------------------------------------
    lane_width: float = param(3.5, low=0.0, low_open=True, doc="m; the main road has two lanes")
    sidewalk_width: float = param(3.0, low=0.0, low_open=True, doc="m")
    first_intersection_x: float = param(50.0, doc="m; centre of the first cross street")
    intersection_spacing: float = param(50.0, low=0.0, low_open=True, doc="m")
    cross_street_width: float = param(7.0, low=0.0, low_open=True, doc="m")
    crosswalk_width: float = param(3.0, low=0.0, low_open=True, doc="m")
    goal_x: float = param(200.0, low=0.0, low_open=True, doc="m; route end (ego centre)")
    # --- Ego vehicle (SPEC §2) -----------------------------------------
    dt: float = param(0.1, low=0.0, low_open=True, doc="s; one tick (paper §V-D)")
    ego_length: float = param(4.5, low=0.0, low_open=True, doc="m")
    ego_width: float = param(1.8, low=0.0, low_open=True, doc="m")
    ego_start_s: float = param(5.0, doc="m; arc length of the box centre at reset")
    setpoint_step: float = param(1.0 * KMH, low=0.0, doc="m/s; +-1 km/h per action")
    setpoint_mode: int = param("measured", choices=SETPOINT_MODES)
    # k > 1: accelerate / slow_down / steer set the setpoint once, at a decision's first tick
    # ("decision", the authors' 1-fps code), or at every tick ("tick"; SPEC §2)
    setpoint_change: int = param("decision", choices=SETPOINT_CHANGES)
    pid_kp: float = param(1.0, low=0.0, doc="per km/h of error")
    pid_ki: float = param(0.05, low=0.0, doc="per km/h·s")
    pid_kd: float = param(0.0, low=0.0, doc="per km/h/s")
    throttle_max: float = param(0.75, low=0.0, high=1.0)
    brake_max: float = param(0.3, low=0.0, high=1.0, doc="PID braking limit (emergency: 1)")
    accel_throttle: float = param(4.0, low=0.0, doc="m/s^2 at full throttle (A_thr)")
    accel_brake: float = param(8.0, low=0.0, doc="m/s^2 at full brake (A_brk)")
    rolling_resistance: float = param(0.1, low=0.0, doc="m/s^2, only while moving")
    accel_lag: float = param(0.3, low=0.0, low_open=True, doc="s; first-order lag tau")
    max_vehicle_speed: float = param(50.0 * KMH, low=0.0, low_open=True, doc="m/s")
    # --- Pedestrians (SPEC §3) -----------------------------------------
    ped_radius: float = param(0.3, low=0.0, low_open=True, doc="m")
    ped_speed_min: float = param(0.5 * KMH, low=0.0, doc="m/s (paper: 0.5 km/h)")
    ped_speed_max: float = param(1.5 * KMH, low=0.0, doc="m/s (paper: 1.5 km/h)")
    prob_crossing: float = param(0.6, low=0.0, high=1.0)
    prob_jaywalking: float = param(0.2, low=0.0, high=1.0)
    prob_sidewalk: float = param(0.2, low=0.0, high=1.0)
    jaywalk_angle_min: float = param(
        math.radians(60.0), low=0.0, high=math.pi, low_open=True, high_open=True, doc="rad"
    )
    jaywalk_angle_max: float = param(
        math.radians(120.0), low=0.0, high=math.pi, low_open=True, high_open=True, doc="rad"
    )
    sidewalk_walk_min: float = param(10.0, low=0.0, doc="m")
    sidewalk_walk_max: float = param(30.0, low=0.0, doc="m")
    walk_on_min: float = param(2.0, low=0.0, doc="m walked on after crossing")
    walk_on_max: float = param(6.0, low=0.0, doc="m walked on after crossing")
    spawn_initial_min: float = param(-5.0, doc="m ahead of the ego centre")
    spawn_initial_max: float = param(40.0, doc="m ahead of the ego centre")
    spawn_min: float = param(10.0, doc="m ahead of the ego centre")
    spawn_max: float = param(40.0, doc="m ahead of the ego centre")
    despawn_behind: float = param(5.0, low=0.0, doc="m behind the ego's rear")
    despawn_ahead: float = param(45.0, low=0.0, doc="m ahead of the ego centre")
    ped_clearance: float = param(0.2, low=0.0, doc="m; footprint inflation pedestrians respect")
    # "ignore": walk the path regardless of the car (the authors' CARLA walkers, the paper's
    # world); "yield": wait, at most ped_wait_max_s, rather than overlap the ego (SPEC §3)
    ped_behaviour_to_car: int = param("ignore", choices=PED_BEHAVIOURS_TO_CAR)
    ped_wait_max_s: float = param(5.0, low=0.0, doc="s; longest yielding wait (CARLA: 5 s)")
    gap_acceptance: int = param(0, low=0, high=1, doc="1: wait at the kerb for the ego")
    wait_distance: float = param(10.0, low=0.0, doc="m; gap acceptance distance")
    wait_time: float = param(3.0, low=0.0, doc="s; gap acceptance time to arrive")
    # --- Observation (SPEC §4) -----------------------------------------
    speed_channel: int = param("pedestrian", choices=SPEED_CHANNELS)
    semantic_channel: int = param("pedestrian", choices=SEMANTIC_CHANNELS)
    speed_norm_pedestrian: float = param(2.0, low=0.0, low_open=True, doc="m/s")
    speed_norm_relative: float = param(6.0, low=0.0, low_open=True, doc="m/s")
    # per pedestrian and step: left out of the grid (partial observability; paper: 0)
    occlusion_prob: float = param(0.0, low=0.0, high=1.0)
    # --- Reward and TTC (SPEC §5) --------------------------------------
    v_ref: float = param(15.0 * KMH, low=0.0, low_open=True, doc="m/s; speed limit")
    stopped_speed: float = param(0.1, low=0.0, doc="m/s; below it the ego counts as stopped")
    ttc_threshold: float = param(3.0, low=0.0, doc="s; near-collision when TTC <= it")
    # what TTC projects (SPEC §5): "contact", the footprint overlapping a disc; "collision",
    # collision_model's test (under "authors" its zone, which spans the lane)
    reward_ttc_test: int = param("contact", choices=TTC_TESTS)
    reward_near_collision_weight: float = param(
        1.0, low=0.0, doc="w in r_nc = w (TTC - 3) (paper: 1)"
    )
    # "contact": box and disc overlap; "authors": a pedestrian on the ego's lane within
    # -2.2..3.5 m along and 2.2 m across the ego's centre (carla-gym; SPEC §5)
    collision_model: int = param("authors", choices=COLLISION_MODELS)
    authors_zone_back: float = param(2.2, low=0.0, doc="m behind the ego centre ('authors')")
    authors_zone_front: float = param(3.5, low=0.0, doc="m ahead of the ego centre ('authors')")
    authors_zone_half_width: float = param(2.2, low=0.0, doc="m either side ('authors')")
    reward_collision: float = param(-10.0, high=0.0, doc="r_c")
    reward_stopped: float = param(-1.0, low=-10.0, high=1.0)
    reward_overspeed: float = param(-0.5, low=-10.0, high=1.0)

    def __post_init__(self) -> None:
        validate(self)
        for name in ("ped_speed", "jaywalk_angle", "sidewalk_walk", "walk_on", "spawn_initial"):
            check_order(self, f"{name}_min", f"{name}_max")
        check_order(self, "spawn_min", "spawn_max")
        check_order(self, "ped_speed_max", "max_vehicle_speed")
        check_sums_to_one(self, ("prob_crossing", "prob_jaywalking", "prob_sidewalk"))


def check_compatible(static: StaticEnvParams, params: EnvParams) -> None:
    """Cross-checks between static and traced parameters (concrete values only)."""
    threshold = params.ttc_threshold
    if is_concrete(threshold) and np.any(np.asarray(threshold) > static.ttc_horizon + 1e-9):
        raise ValueError(
            f"EnvParams.ttc_threshold = {params.ttc_threshold!r}: must be <= "
            f"StaticEnvParams.ttc_horizon ({static.ttc_horizon!r})"
        )
    if static.num_intersections > 1:
        spacing = params.intersection_spacing
        least = params.cross_street_width + 2.0 * params.crosswalk_width
        if is_concrete((spacing, least)) and np.any(np.asarray(spacing) < np.asarray(least)):
            raise ValueError(
                f"EnvParams.intersection_spacing = {show_value(spacing)}: must be >= "
                f"cross_street_width + 2 * crosswalk_width ({show_value(least)}), or the "
                "crosswalks of one intersection lie on the next one's cross street"
            )
