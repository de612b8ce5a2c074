"""Gymnasium API: ``gymnasium.make`` / ``make_vec`` of the drqn_jax ids (SPEC §1–5).

Gymnasium's own ``check_env`` (warnings as errors), a hand-written vector-env
checker (spaces, batches, seeding, both auto-reset modes, agreement with
Gymnasium's ``SyncVectorEnv`` over single envs, independence of ``num_envs``,
``RecordEpisodeStatistics``), invalid actions, rendering, registration, and a
third-party client written only against the Gymnasium API.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.utils.env_checker import check_env, data_equivalence
from gymnasium.vector import AutoresetMode

import drqn_jax
from drqn_jax.env import viewer
from drqn_jax.env.grid import GRID_HIGH, GRID_LOW
from drqn_jax.env.state import NO_ACTION
from drqn_jax.interop import gymnasium_env as ge
from drqn_jax.interop import gymnasium_vector as gv

ID = "drqn_jax/UrbanPedestrians-v0"
ID_REALISTIC = "drqn_jax/UrbanPedestriansRealistic-v0"
SHORT = 5  # max_steps of the short-episode envs
N = 2  # sub-environments of the vector envs (one compile per batch size)


def no_warnings() -> warnings.catch_warnings:
    """A context in which any warning is an error."""
    return warnings.catch_warnings(action="error")


@pytest.fixture(scope="module")
def short_env():
    """A single env whose episodes are truncated after ``SHORT`` steps."""
    return gymnasium.make(ID, max_steps=SHORT)


def make_vec(num_envs: int, mode: AutoresetMode = AutoresetMode.NEXT_STEP, **kw):
    return gymnasium.make_vec(ID, num_envs=num_envs, autoreset_mode=mode, max_steps=SHORT, **kw)


def make_sync(num_envs: int, mode: AutoresetMode):
    """Gymnasium's own SyncVectorEnv over ``num_envs`` single envs."""
    return gymnasium.make_vec(
        ID,
        num_envs=num_envs,
        vectorization_mode="sync",
        vector_kwargs={"autoreset_mode": mode},
        max_steps=SHORT,
    )


# --- registration -------------------------------------------------------------
def test_registration_ids_entry_points_and_idempotence():
    ids = (
        (ID, "UrbanPedestrians-v0"),
        (ID_REALISTIC, "UrbanPedestriansRealistic-v0"),
        ("drqn_jax/UrbanPedestriansHeedless-v0", "UrbanPedestriansHeedless-v0"),
        ("drqn_jax/UrbanPedestriansMixed-v0", "UrbanPedestriansMixed-v0"),
        ("drqn_jax/UrbanPedestriansYielding-v0", "UrbanPedestriansYielding-v0"),
        ("drqn_jax/UrbanPedestriansOccluded-v0", "UrbanPedestriansOccluded-v0"),
        ("drqn_jax/UrbanPedestriansUnseenMap-v0", "UrbanPedestriansUnseenMap-v0"),
    )
    for gym_id, env_id in ids:
        spec = gymnasium.spec(gym_id)
        assert spec.entry_point == "drqn_jax.interop.gymnasium_env:UrbanPedestriansGymEnv"
        assert (
            spec.vector_entry_point == "drqn_jax.interop.gymnasium_vector:UrbanPedestriansVectorEnv"
        )
        assert spec.kwargs == {"env_id": env_id}
    assert set(ge.gymnasium_ids()) == {gym_id for gym_id, _ in ids}
    with no_warnings():
        assert drqn_jax.register_gymnasium_envs() == ge.gymnasium_ids()  # no re-registration


def test_import_emits_no_warnings():
    code = "import drqn_jax, gymnasium; assert 'drqn_jax/UrbanPedestrians-v0' in gymnasium.registry"
    result = subprocess.run(
        [sys.executable, "-W", "error", "-c", code], capture_output=True, text=True
    )
    assert result.returncode == 0, result.stderr


def test_kwargs_reach_drqn_jax_make():
    env = gymnasium.make(ID_REALISTIC, max_steps=300, num_pedestrians=4)
    assert env.unwrapped.jax_env.static.max_steps == 300
    assert env.unwrapped.jax_env.static.num_pedestrians == 4
    assert env.unwrapped.params.ped_speed_max == pytest.approx(1.5)  # the preset's
    with pytest.raises(ValueError, match="no_such_field"):
        gymnasium.make(ID, no_such_field=1)


def test_decision_steps_reach_gymnasium_single_and_vector_envs():
    """``decision_steps`` is an env field like any other: a step is one k-tick decision,
    the info the decision's scalars."""
    env = gymnasium.make(ID, max_steps=20, decision_steps=4)
    assert env.unwrapped.jax_env.static.decision_steps == 4
    env.reset(seed=0)
    *_, info = env.step(0)
    assert info["time"] == 4 and "ticks" not in info
    vec = gymnasium.make_vec(
        ID, num_envs=2, vectorization_mode="vector_entry_point", max_steps=20, decision_steps=4
    )
    vec.reset(seed=0)
    *_, infos = vec.step(np.zeros(2, np.int64))
    np.testing.assert_array_equal(infos["time"], [4, 4])


# --- the single env -------------------------------------------------------------
@pytest.mark.parametrize("gym_id", [ID, ID_REALISTIC])
def test_check_env_passes_without_warnings(gym_id):
    with no_warnings():
        env = gymnasium.make(gym_id)
        check_env(env.unwrapped)
        check_env(gymnasium.make(gym_id))


def test_observation_space_has_the_true_bounds():
    env = gymnasium.make(ID)
    space = env.observation_space
    grid = space["grid"]
    assert grid.shape == (45, 30, 4) and grid.dtype == np.float32
    for ch in (0, 1, 3):  # the JAX env's bounds
        assert np.all(grid.low[..., ch] == GRID_LOW[ch])
        assert np.all(grid.high[..., ch] == GRID_HIGH[ch])
    assert np.all(grid.low[..., 2] == 0.0)

    def tight(high, exact):  # the exact bound, widened only by the 1e-5 float32 margin
        return np.all(high >= np.float32(exact)) and np.all(high <= exact * (1 + 2e-5))

    # ch2: pedestrian speed / 2 m/s; pedestrians walk at most 1.5 km/h (SPEC §3, §4).
    assert tight(grid.high[..., 2], 1.5 / 3.6 / 2.0)
    realistic = gymnasium.make(ID_REALISTIC).observation_space["grid"]
    assert tight(realistic.high[..., 2], 1.5 / 2.0)  # 1.5 m/s
    speed = space["speed"]
    assert speed.shape == (1,) and speed.dtype == np.float32 and speed.low[0] == 0.0
    assert tight(speed.high, 50.0 / 15.0)  # max vehicle speed / v_ref
    last = space["last_action"]
    assert last == gymnasium.spaces.Discrete(5)  # SB3 takes only Discrete spaces from 0
    assert env.action_space == gymnasium.spaces.Discrete(4)


def test_observations_stay_in_space_with_relative_speed_channel():
    """Driving flat out with ``speed_channel="relative"`` never leaves the space."""
    env = gymnasium.make(ID, speed_channel="relative")
    high = env.observation_space["grid"].high[0, 0, 2]
    assert 2.38 < high < 2.39  # (50 km/h + 1.5 km/h) / 6 m/s
    obs, _ = env.reset(seed=5)
    largest = 0.0
    for _ in range(150):
        obs, _, terminated, truncated, _ = env.step(0)
        assert obs in env.observation_space
        largest = max(largest, float(obs["grid"][..., 2].max()))
        if terminated or truncated:
            obs, _ = env.reset()
    assert largest > 1.0  # the channel reached the ego's speed range


def test_reset_seed_reproducible_and_unseeded_continues_stream():
    env = gymnasium.make(ID)
    a, _ = env.reset(seed=3)
    b, _ = env.reset()
    a2, _ = env.reset(seed=3)
    b2, _ = env.reset()
    assert data_equivalence(a, a2, exact=True) and data_equivalence(b, b2, exact=True)
    assert not np.array_equal(a["grid"], b["grid"])
    actions = [0, 0, 3, 1, 0, 2, 3, 0, 0, 1] * 2
    runs = []
    for _ in range(2):
        env.reset(seed=11)
        runs.append([env.step(act) for act in actions])
    assert data_equivalence(runs[0], runs[1], exact=True)


def test_single_env_is_the_jax_env_with_the_documented_keys(short_env):
    """Reset draws a key from np_random and splits it; steps split the held key."""
    jax_env, params = drqn_jax.make("UrbanPedestrians-v0", max_steps=SHORT)
    rng, _ = seeding.np_random(42)
    key = jax.random.wrap_key_data(rng.integers(0, 2**32, size=(2,), dtype=np.uint32))
    key, reset_key = jax.random.split(key)
    obs_j, state = jax.jit(jax_env.reset_env)(reset_key, params)
    obs_g, _ = short_env.reset(seed=42)
    step_env = jax.jit(jax_env.step_env)
    for action in [0, 0, 3, 1, 2]:
        assert np.array_equal(obs_g["grid"], np.asarray(obs_j.grid))
        assert obs_g["speed"][0] == np.asarray(obs_j.speed)
        last = int(obs_j.last_action)
        assert obs_g["last_action"] == (ge.NO_ACTION_YET if last == NO_ACTION else last)
        key, step_key = jax.random.split(key)
        obs_j, state, r, term, trunc, info = step_env(step_key, state, action, params)
        obs_g, r_g, term_g, trunc_g, info_g = short_env.step(action)
        assert (r_g, term_g, trunc_g) == (float(r), bool(term), bool(trunc))
        for name in ("collision", "goal", "ttc", "distance", "speed", "time"):
            assert info_g[name] == np.asarray(info[name]), name
    assert trunc_g and not term_g  # SHORT steps: truncated, as the JAX env says


def test_step_types_and_info(short_env):
    short_env.reset(seed=0)
    obs, reward, terminated, truncated, info = short_env.step(np.int64(0))
    assert type(reward) is float and -10.0 <= reward <= 1.0
    assert type(terminated) is bool and type(truncated) is bool
    assert isinstance(info["collision"], bool) and isinstance(info["goal"], bool)
    for name in ("ttc", "distance", "speed"):
        assert isinstance(info[name], np.float32), name
    assert info["time"] == 1 and obs["last_action"] == 0
    assert isinstance(obs["last_action"], np.int64)


@pytest.mark.parametrize("action", [4, -1, 1.5, "a", np.array([0, 1]), None, np.float32(1.0)])
def test_invalid_action_raises_value_error(short_env, action):
    short_env.reset(seed=0)
    with pytest.raises(ValueError) as err:
        short_env.step(action)
    assert repr(action) in str(err.value) and "Discrete(4)" in str(err.value)


def test_step_before_reset_raises():
    with pytest.raises(ResetNeeded):
        gymnasium.make(ID, max_steps=SHORT).step(0)


def test_render_rgb_array_follows_the_ego():
    env = gymnasium.make(ID, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first.shape == (240, 480, 3) and first.dtype == np.uint8
    for _ in range(40):
        env.step(0)  # accelerate
    assert env.unwrapped.state.ego.s > 8.0
    second = env.render()
    assert second.shape == first.shape and second.dtype == np.uint8
    assert not np.array_equal(first, second)
    # The ego stays at the same pixels: column behind * ppm, the right lane's rows.
    ego_row = round((viewer.RENDER_HALF_WIDTH_M + 1.75) * viewer.RENDER_PIXELS_PER_M)
    ego_col = round(viewer.RENDER_BEHIND_M * viewer.RENDER_PIXELS_PER_M)
    for frame in (first, second):
        assert tuple(frame[ego_row, ego_col]) in (viewer.EGO_COLOUR, viewer.EGO_COLLISION_COLOUR)
        colours = {tuple(c) for c in frame.reshape(-1, 3)}
        assert {viewer.MAP_COLOURS[c] for c in range(4)} <= colours  # map classes drawn
        assert colours & set(viewer.BEHAVIOUR_COLOURS.values())  # and pedestrians


def test_compiled_once_per_static_env():
    a = gymnasium.make(ID)
    a.reset(seed=0)
    a.step(0)
    fns = ge.batch_fns(a.unwrapped.jax_env)
    before = (fns.reset._cache_size(), fns.step_next._cache_size())
    b = gymnasium.make(ID_REALISTIC)  # same static settings, other EnvParams
    assert ge.batch_fns(b.unwrapped.jax_env) is fns
    b.reset(seed=1)
    b.step(3)
    assert (fns.reset._cache_size(), fns.step_next._cache_size()) == before


# --- the vector env ---------------------------------------------------------------
def test_vector_spaces_and_batch_shapes():
    n = N
    env = make_vec(n)
    assert isinstance(env, gv.UrbanPedestriansVectorEnv)
    assert env.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    single = gymnasium.make(ID, max_steps=SHORT)
    assert env.single_observation_space == single.observation_space
    assert env.single_action_space == gymnasium.spaces.Discrete(4)
    assert env.action_space == gymnasium.spaces.MultiDiscrete([4] * n)
    assert env.observation_space["grid"].shape == (n, 45, 30, 4)
    assert env.observation_space["speed"].shape == (n, 1)
    assert env.observation_space["last_action"] == gymnasium.spaces.MultiDiscrete([5] * n)
    obs, info = env.reset(seed=0)
    assert obs in env.observation_space and info == {}
    assert np.all(obs["last_action"] == ge.NO_ACTION_YET)
    env.action_space.seed(0)
    for _ in range(2 * SHORT + 2):
        obs, rewards, terminated, truncated, info = env.step(env.action_space.sample())
        assert obs in env.observation_space
        assert obs["grid"].dtype == np.float32 and obs["last_action"].dtype == np.int64
        assert rewards.shape == (n,) and rewards.dtype == np.float64
        assert terminated.shape == truncated.shape == (n,) and terminated.dtype == np.bool_
        for name, value in info.items():
            assert value.shape == (n,), name
    with pytest.raises(ValueError, match="num_envs"):
        make_vec(0)


def test_vector_seeding_determinism():
    actions = np.random.default_rng(1).integers(0, 4, size=(20, 2))

    def run(seed):
        env = make_vec(2)
        out = [env.reset(seed=seed)[0]]
        out += [env.step(a)[0] for a in actions]
        return out

    first, again, other = run(17), run(17), run(18)
    assert data_equivalence(first, again, exact=True)
    assert not np.array_equal(first[0]["grid"], other[0]["grid"])
    # An int seed s seeds sub-environment i with s + i, as a list would.
    env = make_vec(2)
    a, _ = env.reset(seed=[17, 18])
    assert data_equivalence(a, first[0], exact=True)
    # An unseeded reset continues each sub-environment's stream.
    b, _ = env.reset()
    c, _ = make_vec(2).reset(seed=17)
    assert not np.array_equal(b["grid"], c["grid"])


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_vector_env_equals_sync_vector_env_of_single_envs(mode):
    """Bit for bit what Gymnasium's SyncVectorEnv gives over ``gymnasium.make`` envs,
    final observations, ``final_info`` and ``_key`` masks included."""
    n = N
    native, sync = make_vec(n, mode), make_sync(n, mode)
    assert native.metadata["autoreset_mode"] == sync.metadata["autoreset_mode"] == mode
    assert data_equivalence(native.reset(seed=7), sync.reset(seed=7), exact=True)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(3 * SHORT):
        actions = rng.integers(0, 4, size=n)
        got, want = native.step(actions), sync.step(actions)
        assert data_equivalence(got, want, exact=True)
        ended += int(np.sum(got[2] | got[3]))
    assert ended >= 2 * n  # several episodes ended and auto-reset


def test_next_step_autoreset_contract():
    env = make_vec(2, AutoresetMode.NEXT_STEP)
    env.reset(seed=3)
    for _ in range(SHORT):
        obs, rewards, terminated, truncated, info = env.step(np.array([0, 2]))
    assert np.all(truncated | terminated)
    assert np.all(info["_time"]) and np.all(info["time"][truncated] == SHORT)
    obs, rewards, terminated, truncated, info = env.step(np.array([1, 3]))  # actions ignored
    assert np.all(rewards == 0.0) and not terminated.any() and not truncated.any()
    assert np.all(obs["last_action"] == ge.NO_ACTION_YET) and info == {}
    assert np.all(np.asarray(env.unwrapped.states.time) == 0)
    obs, *_, info = env.step(np.array([1, 3]))
    assert np.all(obs["last_action"] == [1, 3]) and np.all(info["time"] == 1)


def test_same_step_autoreset_contract():
    env = make_vec(2, AutoresetMode.SAME_STEP)
    env.reset(seed=3)
    for _ in range(SHORT - 1):
        *_, info = env.step(np.array([0, 2]))
        assert "final_obs" not in info
    obs, _, terminated, truncated, info = env.step(np.array([0, 2]))
    done = terminated | truncated
    assert np.all(done)
    assert np.all(obs["last_action"] == ge.NO_ACTION_YET)  # already the next episode
    assert np.all(info["_final_obs"] == done) and np.all(info["_final_info"] == done)
    assert info["final_obs"].dtype == object
    for i, action in enumerate([0, 2]):
        final = info["final_obs"][i]
        assert final in env.single_observation_space and final["last_action"] == action
    assert np.all(info["final_info"]["time"] == SHORT) and np.all(info["final_info"]["_time"])
    assert "time" not in info  # the reset sub-environments have no step info
    assert np.all(np.asarray(env.unwrapped.states.time) == 0)


def test_sub_environment_results_do_not_depend_on_num_envs():
    """Sub-environment i of a batch seeded with s equals a batch of one seeded with s + i.

    (For SAME_STEP, agreement with SyncVectorEnv over single envs shows the same.)
    """
    mode = AutoresetMode.NEXT_STEP
    actions = np.random.default_rng(2).integers(0, 4, size=(2 * SHORT + 3, N))
    batch = make_vec(N, mode)
    runs = [[batch.reset(seed=20)[0]] + [batch.step(a)[0] for a in actions]]
    for i in range(N):
        one = make_vec(1, mode)
        obs = [one.reset(seed=20 + i)[0]] + [one.step(a[i : i + 1])[0] for a in actions]
        for got, want in zip(obs, runs[0], strict=True):
            for name in got:
                assert np.array_equal(got[name][0], want[name][i]), (i, name)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_record_episode_statistics(mode):
    env = gymnasium.wrappers.vector.RecordEpisodeStatistics(make_vec(2, mode))
    env.reset(seed=4)
    running = np.zeros(2)
    pending_reset = np.zeros(2, bool)
    reported = 0
    for action in np.random.default_rng(3).integers(0, 4, size=(3 * SHORT, 2)):
        _, rewards, terminated, truncated, info = env.step(action)
        if mode == AutoresetMode.NEXT_STEP:
            running[pending_reset] = 0.0
            assert np.all(rewards[pending_reset] == 0.0)
        running += rewards
        done = terminated | truncated
        if done.any():
            episode = info["episode"]
            assert np.array_equal(info["_episode"], done)
            np.testing.assert_allclose(episode["r"][done], running[done], rtol=1e-12)
            assert np.all(episode["l"][done] <= SHORT)
            reported += int(done.sum())
        if mode == AutoresetMode.SAME_STEP:
            running[done] = 0.0
        pending_reset = done
    assert reported >= 4 and len(env.return_queue) == reported


def test_invalid_vector_actions_raise_value_error():
    env = make_vec(2)
    env.reset(seed=0)
    for actions in (np.array([0, 4]), np.array([-1, 0]), np.array([0.0, 1.0]), np.array([0])):
        with pytest.raises(ValueError) as err:
            env.step(actions)
        assert repr(actions) in str(err.value) and "MultiDiscrete([4 4])" in str(err.value)
    with pytest.raises(ResetNeeded):
        make_vec(2).step(np.array([0, 0]))


def test_disabled_autoreset_and_reset_mask():
    env = make_vec(2, AutoresetMode.DISABLED)
    assert env.metadata["autoreset_mode"] is AutoresetMode.DISABLED
    env.reset(seed=9)
    for _ in range(SHORT):
        obs, _, terminated, truncated, _ = env.step(np.array([0, 0]))
    assert np.all(terminated | truncated)
    with pytest.raises(ResetNeeded, match="reset_mask"):
        env.step(np.array([0, 0]))
    mask = np.array([True, False])
    obs1, info = env.reset(options={"reset_mask": mask})
    assert info == {} and obs1["last_action"][0] == ge.NO_ACTION_YET
    assert np.array_equal(obs1["grid"][1], obs["grid"][1])  # sub-environment 1 untouched
    # Sub-environment 0's second episode is the one SyncVectorEnv would start.
    sync = make_sync(2, AutoresetMode.DISABLED)
    sync.reset(seed=9)
    for _ in range(SHORT):
        sync.step(np.array([0, 0]))
    want, _ = sync.reset(options={"reset_mask": mask})
    assert np.array_equal(obs1["grid"][0], want["grid"][0])
    with pytest.raises(ResetNeeded):
        env.step(np.array([0, 0]))  # sub-environment 1 still ended
    env.reset(options={"reset_mask": ~mask})
    env.step(np.array([0, 0]))


def test_vector_render():
    env = make_vec(2, render_mode="rgb_array")
    env.reset(seed=0)
    frames = env.render()
    assert len(frames) == 2
    assert all(f.shape == (240, 480, 3) and f.dtype == np.uint8 for f in frames)
    assert not np.array_equal(frames[0], frames[1])  # different pedestrians


# --- a third-party client ------------------------------------------------------------
def test_third_party_linear_q_learning_client():
    """Linear Q-learning in NumPy, written only against the Gymnasium API and wrappers."""
    with no_warnings():
        env = gymnasium.make(ID)
        env = gymnasium.wrappers.TimeLimit(env, max_episode_steps=60)
        env = gymnasium.wrappers.RecordEpisodeStatistics(env)
        env = gymnasium.wrappers.FlattenObservation(env)
        n_features = gymnasium.spaces.flatdim(env.observation_space)
        assert env.observation_space.shape == (n_features,) == (45 * 30 * 4 + 5 + 1,)
        n_actions = int(env.action_space.n)
        weights = np.zeros((n_actions, n_features + 1))
        rng = np.random.default_rng(0)
        env.action_space.seed(0)
        obs, _ = env.reset(seed=0)
        returns = []
        for _ in range(300):
            x = np.append(obs, 1.0)
            q = weights @ x
            action = env.action_space.sample() if rng.random() < 0.3 else int(np.argmax(q))
            next_obs, reward, terminated, truncated, info = env.step(action)
            assert next_obs in env.observation_space
            bootstrap = 0.0 if terminated else 0.9 * np.max(weights @ np.append(next_obs, 1.0))
            weights[action] += 0.01 * (reward + bootstrap - q[action]) * x
            obs = next_obs
            if terminated or truncated:
                returns.append(info["episode"]["r"])
                obs, _ = env.reset()
    assert len(returns) >= 4
    assert np.all(np.isfinite(weights)) and np.any(weights != 0.0)


_SB3_CLIENT = """
import json, warnings
import gymnasium, drqn_jax
from stable_baselines3 import DQN, PPO
from stable_baselines3.common.env_checker import check_env

env = gymnasium.make("drqn_jax/UrbanPedestrians-v0", max_steps=100)
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    check_env(env.unwrapped)
dqn = DQN("MultiInputPolicy", env, learning_starts=100, buffer_size=1000, seed=0)
dqn.learn(300)
ppo = PPO("MultiInputPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0)
ppo.learn(128)
print(json.dumps({
    "warnings": [str(w.message) for w in caught],
    "dqn_steps": dqn.num_timesteps, "dqn_updates": dqn._n_updates,
    "ppo_steps": ppo.num_timesteps,
}))
"""


def test_stable_baselines3_trains_on_the_registered_id_without_wrappers():
    """SB3's DQN and PPO with ``MultiInputPolicy`` take the env as ``gymnasium.make``
    returns it (``Discrete(5, start=-1)`` would crash SB3's one-hot encoding).
    In a child process: torch and this worker's JAX programs stay apart."""
    out = subprocess.run(
        [sys.executable, "-c", _SB3_CLIENT], capture_output=True, text=True, timeout=600
    )
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    # SB3 still calls the float grid "an image"; nothing may concern last_action.
    assert not [w for w in result["warnings"] if "last_action" in w], result["warnings"]
    assert result["dqn_steps"] == 300 and result["dqn_updates"] > 0
    assert result["ppo_steps"] == 128


@pytest.mark.parametrize("restarting", [(), (1, 4, 10), tuple(range(12))])
def test_the_vector_env_resets_exactly_the_envs_that_restart(restarting):
    """Issue 42: a vector step computes fresh episodes only for the envs that restart
    (none; a few in one pass; more than RESETS_PER_PASS in several), and each gets
    exactly the episode (state and observation) its own reset key gives."""
    env, params = drqn_jax.make()
    n = 12
    assert len(restarting) == 0 or len(restarting) <= ge.RESETS_PER_PASS < n or len(restarting) == n
    mask = np.isin(np.arange(n), restarting)
    keys = jax.random.split(jax.random.key(7), 3 * n)
    states = jax.jit(jax.vmap(env.reset_state, (0, None)))(keys[:n], params)
    obs = jax.jit(jax.vmap(env.observation, (0, None)))(states, params)
    held = jax.random.key_data(keys[n : 2 * n])
    reset_data = jax.random.key_data(keys[2 * n :])
    restart = jax.jit(lambda *a: ge._restart_where(env, *a))
    new = restart(mask, reset_data, held, obs, states, params)

    def row(tree, i):
        return jax.tree.map(lambda x: x[i], tree)

    for i in range(n):
        if mask[i]:
            want = ge.single_reset(env, reset_data[i], params)
        else:
            want = held[i], row(obs, i), row(states, i)
        got = row(new, i)
        assert all(
            np.array_equal(a, b)
            for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True)
        ), i
