"""The JAX env against a plain NumPy implementation (``tests/env/numpy_env.py``).

Both envs start from the same key and take the same actions; the NumPy env
consumes the very uniforms the JAX env draws (``jax_draws``: one (8, P) array
per reset and per step, see ``spawn_pedestrians``), and each runs on its own
state, so the trajectories are compared end to end, not re-synchronised.

Tolerances:

* discrete values must be equal: termination and truncation, collision, goal,
  behaviours, waypoint indices, the PID count, last action, time, and the TTC
  (a sample time out of {0, 0.1, …, 3} ∪ {inf});
* continuous values ``assert_allclose(rtol=1e-5, atol=1e-5)``. In these
  scenarios they agree to the bit except pedestrian headings (by one or two
  ulps), because the NumPy env repeats XLA's float32 operations in XLA's order,
  including its rewrites of divisions into products with a reciprocal; XLA's
  ``atan2`` (and ``cos``, ``sin``) are glibc's float32 functions, the NumPy
  env's are float64 ones rounded to float32, which sometimes differ by an ulp;
* the grid: occupancy (channel 0) must be equal cell by cell, the other
  channels to the tolerance above. The only way float rounding could move a
  pedestrian to another cell is a position that differs by an ulp (jaywalking
  waypoints use ``cos``/``sin``, which may round differently) on a cell edge:
  :func:`assert_grids_match` exempts exactly the two cells of such a
  pedestrian, after checking that its two positions agree to the tolerance.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import numpy as np
import pytest

import drqn_jax
from drqn_jax.env.state import ACCELERATE
from tests.env import numpy_env as npe

RTOL = ATOL = 1e-5
# Values that are discrete (flags, codes, counters, TTC sample times): compared exactly.
EXACT = {
    "behaviour",
    "visible",
    "waypoint_index",
    "pid_count",
    "last_action",
    "time",
    "terminated",
    "truncated",
    "collision",
    "goal",
    "ttc",
}
SWITCHED = {
    "setpoint_mode": "setpoint",
    "speed_channel": "relative",
    "semantic_channel": "map",
    "gap_acceptance": 1,
    "reward_ttc_test": "collision",
    "reward_near_collision_weight": 0.5,
}


class Scenario(NamedTuple):
    """One compared rollout and the events it must contain (so coverage is checked)."""

    env_id: str
    overrides: dict[str, Any]
    policy: str  # "random", "driving" (mostly accelerate) or "accelerate"
    seed: int
    steps: int
    expect: tuple[str, ...] = ()


SCENARIOS = {
    **{f"random-{s}": Scenario("UrbanPedestrians-v0", {}, "random", s, 250) for s in range(5)},
    "accelerate": Scenario(
        "UrbanPedestrians-v0", {}, "accelerate", 2, 250, ("collision", "goal", "near_miss")
    ),
    "driving": Scenario(
        "UrbanPedestrians-v0", {}, "driving", 2, 300, ("collision", "goal", "near_miss")
    ),
    "realistic-accelerate": Scenario(
        "UrbanPedestriansRealistic-v0", {}, "accelerate", 0, 200, ("collision", "near_miss")
    ),
    "realistic-driving": Scenario(
        "UrbanPedestriansRealistic-v0", {}, "driving", 2, 250, ("collision", "near_miss")
    ),
    "mixed": Scenario(
        "UrbanPedestriansMixed-v0", {}, "driving", 0, 250, ("collision", "near_miss")
    ),
    "switches": Scenario(
        "UrbanPedestrians-v0", SWITCHED, "driving", 0, 300, ("collision", "near_miss")
    ),
    "occlusion": Scenario(
        "UrbanPedestrians-v0", {"occlusion_prob": 0.3}, "driving", 1, 250, ("occluded",)
    ),
    "heedless": Scenario(  # pedestrians ignore the car, contact collisions
        "UrbanPedestriansHeedless-v0", {}, "driving", 3, 300, ("collision", "goal", "near_miss")
    ),
    "struck": Scenario(  # the paper's world: walkers into the standing car
        "UrbanPedestrians-v0", {}, "random", 0, 300, ("collision", "struck")
    ),
    "yielding": Scenario(  # pedestrians wait for the car, at most 5 s, then strike it
        "UrbanPedestriansYielding-v0", {}, "random", 3, 300, ("collision", "struck", "yielded")
    ),
    "occluded": Scenario(  # the sensitivity world with occlusion p = 0.5
        "UrbanPedestriansOccluded-v0", {}, "driving", 1, 250, ("occluded",)
    ),
    "unseen-map": Scenario(  # 4 intersections 40 m apart, 15 pedestrians
        "UrbanPedestriansUnseenMap-v0", {}, "driving", 0, 300, ("collision",)
    ),
    "truncation": Scenario(
        "UrbanPedestrians-v0", {"max_steps": 100}, "random", 3, 250, ("truncated",)
    ),
}
MAX_STEPS = max(s.steps for s in SCENARIOS.values())  # one key-split shape: one compile


# --- JAX side --------------------------------------------------------------------
@pytest.fixture(scope="module")
def compiled() -> dict[Any, tuple[Any, Any]]:
    """Cache of jitted ``(reset, step)`` by static settings: each compiles once per module."""
    return {}


def jax_env(cache: dict, scenario: Scenario) -> tuple[Any, Any, tuple[Any, Any]]:
    """The JAX env, its params and its jitted ``(reset, step)`` (params traced)."""
    env, params = drqn_jax.make(scenario.env_id, **scenario.overrides)
    if env.static not in cache:
        cache[env.static] = (jax.jit(env.reset), jax.jit(env.step))
    return env, params, cache[env.static]


def actions(policy: str, seed: int, steps: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if policy == "random":
        return rng.integers(0, 4, steps)
    if policy == "driving":  # accelerate, slow_down, brake, steer
        return rng.choice(4, steps, p=[0.6, 0.15, 0.05, 0.2])
    return np.full(steps, ACCELERATE)


# --- records ------------------------------------------------------------------------
def flatten(obj: Any, prefix: str) -> dict[str, np.ndarray]:
    """Leaves of a (JAX or NumPy) state / observation dataclass by dotted name."""
    if dataclasses.is_dataclass(obj):
        out: dict[str, np.ndarray] = {}
        for f in dataclasses.fields(obj):
            out.update(flatten(getattr(obj, f.name), f"{prefix}.{f.name}"))
        return out
    return {prefix: np.asarray(obj)}


def record(obs: Any, state: Any, step: tuple | None = None) -> dict[str, np.ndarray]:
    """What is compared after a reset, or after a step (``step`` = its other outputs)."""
    rec = flatten(obs, "obs") | flatten(state, "state")
    if step is not None:
        r, terminated, truncated, info = step
        rec |= {"reward": np.asarray(r), "terminated": np.asarray(terminated)}
        rec |= {"truncated": np.asarray(truncated)}
        for k in ("collision", "struck_while_stopped", "goal", "ttc", "distance", "speed", "time"):
            rec[f"info.{k}"] = np.asarray(info[k])
        rec |= flatten(info["final_observation"], "final_obs")
        rec |= flatten(info["final_state"], "final_state")
    return rec


def stack(records: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Each leaf over the records that have it: (T + 1, ...) from the reset on for the
    observation and state, (T, ...) from step 1 on for the other step outputs."""
    return {k: np.stack([r[k] for r in records if k in r]) for k in records[-1]}


def rollouts(cache: dict, scenario: Scenario) -> tuple[dict, dict, npe.NumpyUrbanPedestrians]:
    """Both envs' stacked records (JAX, NumPy) over a reset and ``scenario.steps`` steps."""
    env, params, (reset, step) = jax_env(cache, scenario)
    np_env = npe.NumpyUrbanPedestrians(env.static, params)
    keys = jax.random.split(jax.random.key(scenario.seed), MAX_STEPS + 1)
    draws = npe.jax_draws(keys, env.static)  # what reset / step draw from each key

    obs, state = reset(keys[0], params)
    np_obs, np_state = np_env.reset(draws[0])
    ours, theirs = [record(obs, state)], [record(np_obs, np_state)]
    for t, a in enumerate(actions(scenario.policy, scenario.seed, scenario.steps), start=1):
        obs, state, *rest = step(keys[t], state, a, params)
        np_obs, np_state, *np_rest = np_env.step(np_state, a, draws[t])
        ours.append(record(obs, state, tuple(rest)))
        theirs.append(record(np_obs, np_state, tuple(np_rest)))
    return stack(ours), stack(theirs), np_env


# --- comparisons --------------------------------------------------------------------
def assert_grids_match(
    name: str,
    grid_j: np.ndarray,
    grid_n: np.ndarray,
    jx: dict,
    nx: dict,
    np_env: npe.NumpyUrbanPedestrians,
    first_step: int = 0,
) -> None:
    """Grids (T, rows, cols, 4) equal as the module docstring says.

    ``jx`` / ``nx`` hold ``position`` (T, P, 2) and ``s`` (T,) of the JAX / NumPy
    states the grids were rasterised from; record t is step ``first_step + t``.
    """
    size = grid_j.shape[1] * grid_j.shape[2]
    keep = np.ones(grid_j.shape[:3], bool)
    for t in np.nonzero(np.any(grid_j[..., 0] != grid_n[..., 0], axis=(1, 2)))[0]:
        static, params = np_env.static, np_env.params
        cell_j, _ = npe.grid_cell_index(jx["position"][t], jx["s"][t], params, static)
        cell_n, _ = npe.grid_cell_index(nx["position"][t], nx["s"][t], params, static)
        for i in np.nonzero(cell_j != cell_n)[0]:
            np.testing.assert_allclose(
                nx["position"][t, i],
                jx["position"][t, i],
                rtol=RTOL,
                atol=ATOL,
                err_msg=f"{name} at step {first_step + t}: pedestrian {i} is in another "
                "cell, not by rounding",
            )
            for cell in (cell_j[i], cell_n[i]):
                if cell < size:
                    keep[t].reshape(size)[cell] = False
    np.testing.assert_array_equal(
        np.where(keep, grid_n[..., 0], 0), np.where(keep, grid_j[..., 0], 0), err_msg=name
    )
    np.testing.assert_allclose(
        np.where(keep[..., None], grid_n, 0),
        np.where(keep[..., None], grid_j, 0),
        rtol=RTOL,
        atol=ATOL,
        err_msg=name,
    )


def assert_records_match(ours: dict, theirs: dict, np_env: npe.NumpyUrbanPedestrians) -> None:
    """Every leaf equal (discrete) or close (continuous); a failure names the first bad step.

    Grids come last, so that a state that went astray is reported as such.
    """
    assert ours.keys() == theirs.keys()
    num_steps = len(ours["obs.speed"]) - 1  # step 0 is the reset
    for name in sorted(ours, key=lambda k: k.endswith(".grid")):
        j, n = ours[name], theirs[name]
        assert n.dtype == j.dtype, f"{name}: dtype {n.dtype}, JAX {j.dtype}"
        assert n.shape == j.shape, f"{name}: shape {n.shape}, JAX {j.shape}"
        first_step = num_steps + 1 - len(j)
        if name.endswith(".grid"):
            src = "state" if name.startswith("obs") else "final_state"
            jx = {"position": ours[f"{src}.pedestrians.position"], "s": ours[f"{src}.ego.s"]}
            nx = {"position": theirs[f"{src}.pedestrians.position"], "s": theirs[f"{src}.ego.s"]}
            assert_grids_match(name, j, n, jx, nx, np_env, first_step)
            continue
        exact = name.rsplit(".", 1)[-1] in EXACT
        ok = n == j if exact else np.isclose(n, j, rtol=RTOL, atol=ATOL)
        bad = np.nonzero(~ok.reshape(len(ok), -1).all(axis=1))[0]
        if len(bad):
            t = bad[0]
            msg = f"{name} differs first at step {first_step + t} (0: the reset)"
            if exact:
                np.testing.assert_array_equal(n[t], j[t], err_msg=msg)
            np.testing.assert_allclose(n[t], j[t], rtol=RTOL, atol=ATOL, err_msg=msg)


def events(rec: dict) -> set[str]:
    found = {k for k in ("collision", "goal") if rec[f"info.{k}"].any()}
    if rec["truncated"].any():
        found.add("truncated")
    if (rec["info.ttc"] <= 3.0).any():
        found.add("near_miss")
    if not rec["state.pedestrians.visible"].all():
        found.add("occluded")
    if rec["info.struck_while_stopped"].any():
        found.add("struck")
    if (rec["state.pedestrians.waited"] > 0).any():
        found.add("yielded")
    return found


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_trajectories_match(compiled: dict, name: str) -> None:
    scenario = SCENARIOS[name]
    ours, theirs, np_env = rollouts(compiled, scenario)
    assert set(scenario.expect) <= events(ours), f"{name}: expected {scenario.expect}"
    assert_records_match(ours, theirs, np_env)


def test_scenarios_cover_every_registered_world() -> None:
    assert {s.env_id for s in SCENARIOS.values()} == set(drqn_jax.registered_envs())


def test_grid_check_exempts_only_rounding_flips() -> None:
    """The grid check tolerates a pedestrian an ulp across a cell edge, nothing more."""
    np_env = npe.NumpyUrbanPedestrians()
    _, state = np_env.reset(np.random.default_rng(0))
    s = state.ego.s
    edge = np.float32(s + np.float32(10.0))  # a row edge: grid_x_min = -5 m, 1 m cells
    grids, positions = [], []
    for x in (edge, np.nextafter(edge, np.float32(-np.inf)), edge - np.float32(0.5)):
        peds = dataclasses.replace(state.pedestrians, position=state.pedestrians.position.copy())
        peds.position[0] = (x, -5.0)
        grids.append(npe.rasterize_grid(state.ego, peds, np_env.params, np_env.static)[None])
        positions.append(peds.position[None])
    ss = np.array([s])

    def states(i: int) -> dict:
        return {"position": positions[i], "s": ss}

    assert not np.array_equal(grids[0], grids[1])  # the ulp moved it to the previous row
    assert_grids_match("ulp", grids[0], grids[1], states(0), states(1), np_env)
    with pytest.raises(AssertionError, match="not by rounding"):
        assert_grids_match("half", grids[0], grids[2], states(0), states(2), np_env)


def test_step_env_is_step_without_reset() -> None:
    """NumPy ``step_env`` returns ``step``'s final observation and state."""
    np_env = npe.NumpyUrbanPedestrians(drqn_jax.make(max_steps=3)[0].static)
    rng = np.random.default_rng(1)
    _, state = np_env.reset(rng)
    for _ in range(3):
        draws = npe.numpy_draws(rng, np_env.static)
        obs, nxt, r, term, trunc, _ = np_env.step_env(state, ACCELERATE, draws)
        _, state, r2, term2, trunc2, info2 = np_env.step(state, ACCELERATE, draws)
        assert (r, term, trunc) == (r2, term2, trunc2)
        ours = flatten(obs, "obs") | flatten(nxt, "state")
        theirs = flatten(info2["final_observation"], "obs") | flatten(info2["final_state"], "state")
        for k in ours:
            np.testing.assert_array_equal(ours[k], theirs[k], err_msg=k)
    assert trunc2 and int(state.time) == 0  # the third step truncated and reset


def test_generator_draws_and_throughput() -> None:
    """A generator stands in for explicit draws; the benchmark helper runs."""
    np_env = npe.NumpyUrbanPedestrians()
    _, a = np_env.reset(np.random.default_rng(5))
    _, b = np_env.reset(npe.numpy_draws(np.random.default_rng(5), np_env.static))
    for k, v in flatten(a, "state").items():
        np.testing.assert_array_equal(v, flatten(b, "state")[k], err_msg=k)
    assert npe.numpy_steps_per_s(num_steps=50) > 0
