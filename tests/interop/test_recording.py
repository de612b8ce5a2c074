"""Rerun recordings (drqn_jax.interop.recording): read the .rrd back and check it against
the simulator.

The recordings are read with rerun's own reader, ``rerun.chunk.RrdReader(path)
.stream().to_chunks()``, and compared with an independent step-by-step rollout
(``env.reset_env`` / ``env.step_env`` / ``agent.act`` / ``network.step``, each
jitted alone) on the evaluation's per-episode keys.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from functools import partial

import jax
import numpy as np
import pytest
from rerun.chunk import RrdReader

import drqn_jax
from drqn_jax import cli
from drqn_jax.config import load_config
from drqn_jax.env import viewer
from drqn_jax.env.road_map import semantic_class
from drqn_jax.env.state import ACTIONS, BEHAVIOURS
from drqn_jax.evaluation import episode_keys, run_episodes
from drqn_jax.interop import episode_record, recording
from drqn_jax.networks import make_network
from tests.helpers import SMALL_NET

NUM_EPISODES = 2
MAX_STEPS = 30


# --- reading a recording ---------------------------------------------------------


def read_rrd(path) -> dict[str, dict]:
    """``{entity: {"static": {component: value}, "step": (R,) int64, component: [R values]}}``.

    Temporal rows are gathered from every chunk of the entity and sorted by step.
    """
    out: dict[str, dict] = defaultdict(lambda: {"static": {}})
    rows: dict[str, list] = defaultdict(list)
    for chunk in RrdReader(str(path)).stream().to_chunks():
        batch = chunk.to_record_batch()
        names = [n for n in batch.schema.names if n != "rerun.controls.RowId"]
        entity = chunk.entity_path
        if chunk.is_static:
            for name in names:
                out[entity]["static"][name] = batch.column(name).to_pylist()[-1]
            continue
        columns = {name: batch.column(name).to_pylist() for name in names}
        for r in range(chunk.num_rows):
            rows[entity].append({name: columns[name][r] for name in names})
    for entity, entity_rows in rows.items():
        entity_rows.sort(key=lambda row: row["step" if "step" in row else "episode"])
        for name in entity_rows[0]:
            out[entity][name] = [row[name] for row in entity_rows]
        index = "step" if "step" in entity_rows[0] else "episode"
        out[entity][index] = np.asarray(out[entity][index], np.int64)
    return dict(out)


def scalars(entity: dict) -> np.ndarray:
    """(R,) float64 of a Scalars entity with one scalar per row."""
    return np.array([row[0] for row in entity["Scalars:scalars"]], np.float64)


def rgb(packed: int) -> tuple[int, int, int]:
    """rerun's packed 0xRRGGBBAA colour → (r, g, b)."""
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255


def unflip(xy) -> np.ndarray:
    """Logged (x, -y) → simulator (x, y)."""
    return np.asarray(xy, np.float32) * np.array([1.0, -1.0], np.float32)


# --- an independent reference rollout ---------------------------------------------


@partial(jax.jit, static_argnames="env")
def _reset(env, key, params):
    return env.reset_env(key, params)


@partial(jax.jit, static_argnames="env")
def _step(env, key, state, action, params):
    return env.step_env(key, state, action, params)


@partial(jax.jit, static_argnames="env")
def _act(env, agent, key, obs, carry, state, params):
    return agent.act(key, obs, carry, state, env, params)


def reference_episodes(agent, key, env, params, network=None, network_params=None):
    """Episodes played one jitted call at a time; per episode a dict of per-step arrays."""
    reset = partial(_reset, env)
    step = partial(_step, env)
    act = partial(_act, env)
    q_step = None if network is None else jax.jit(network.step)
    episodes = []
    for ep_key in episode_keys(key, NUM_EPISODES):
        key_reset, key_carry, key_run = jax.random.split(ep_key, 3)
        obs, state = reset(key_reset, params)
        carry = agent.init_carry(key_carry)
        q_carry = None if network is None else network.initial_carry(())
        ep = defaultdict(list)
        ep["s"].append(state.ego.s)
        ep["peds"].append(state.pedestrians)
        ep["state"].append(state)
        ep["grid"].append(obs.grid)
        for step_key in jax.random.split(key_run, env.static.max_steps):
            key_act, key_env = jax.random.split(step_key)
            action, carry = act(agent, key_act, obs, carry, state, params)
            if network is not None:
                q, q_carry = q_step(network_params, obs, q_carry)
                ep["q"].append(q)
            obs, state, reward, terminated, truncated, info = step(key_env, state, action, params)
            ep["action"].append(action)
            ep["reward"].append(reward)
            ep["ttc"].append(info["ttc"])
            ep["struck"].append(info["struck_while_stopped"])
            ep["s"].append(state.ego.s)
            ep["peds"].append(state.pedestrians)
            ep["state"].append(state)
            ep["grid"].append(obs.grid)
            if bool(terminated | truncated):
                break
        out = {k: np.asarray(v) for k, v in ep.items() if k not in ("peds", "state")}
        out["peds"] = jax.tree.map(lambda *xs: np.stack(xs), *ep["peds"])
        out["state"] = ep["state"]
        episodes.append(out)
    return episodes


# --- fixtures -------------------------------------------------------------------


@pytest.fixture(scope="module")
def env_params():
    return drqn_jax.make("UrbanPedestrians-v0", max_steps=MAX_STEPS)


@pytest.fixture(scope="module")
def key():
    return jax.random.key(7)


@pytest.fixture(scope="module")
def rule_based(tmp_path_factory, env_params, key):
    """(rrd contents, reference episodes) of the rule-based agent."""
    env, params = env_params
    agent = drqn_jax.rule_based_agent()
    path = tmp_path_factory.mktemp("rec") / "rule_based.rrd"
    record = episode_record.collect_episodes(agent, key, NUM_EPISODES, env, params)
    recording.write_episodes(path, record, env, params)
    return read_rrd(path), reference_episodes(agent, key, env, params)


@pytest.fixture(scope="module")
def drqn(tmp_path_factory, env_params, key):
    """(rrd contents, reference episodes) of a DRQN with a tiny network and random weights."""
    env, params = env_params
    network = make_network(SMALL_NET)
    weights = network.init(jax.random.key(3))
    agent = drqn_jax.drqn_agent(network, weights)
    path = tmp_path_factory.mktemp("rec") / "drqn.rrd"
    record = episode_record.collect_episodes(
        agent, key, NUM_EPISODES, env, params, network=network, network_params=weights
    )
    recording.write_episodes(path, record, env, params)
    return read_rrd(path), reference_episodes(agent, key, env, params, network, weights)


@pytest.fixture(params=["rule_based", "drqn"])
def recorded(request):
    return request.getfixturevalue(request.param)


# --- tests ----------------------------------------------------------------------


def test_recorded_episodes_are_the_evaluated_ones(env_params, key):
    env, params = env_params
    agent = drqn_jax.rule_based_agent()
    record = episode_record.collect_episodes(agent, key, NUM_EPISODES, env, params)
    evaluated = run_episodes(agent, episode_keys(key, NUM_EPISODES), env, params)
    np.testing.assert_array_equal(record.length, evaluated.length)
    np.testing.assert_array_equal(record.episode_return, evaluated.episode_return)
    assert record.grid.shape == (NUM_EPISODES, MAX_STEPS + 1, 45, 30, 4)
    assert record.q_values is None


def test_ego_positions_equal_the_simulated_ones(recorded, env_params):
    rrd, reference = recorded
    _, params = env_params
    for i, ref in enumerate(reference):
        ego = rrd[f"/episode/{i}/world/ego"]
        length = len(ref["action"])
        np.testing.assert_array_equal(ego["step"], np.arange(length + 1))
        centres = unflip([row[0] for row in ego["Boxes2D:centers"]])
        np.testing.assert_array_equal(centres[:, 0], ref["s"])
        np.testing.assert_array_equal(centres[:, 1], np.float32(-0.5 * params.lane_width))
        half = np.array([row[0] for row in ego["Boxes2D:half_sizes"]])
        np.testing.assert_allclose(half, np.broadcast_to([2.25, 0.9], half.shape), rtol=1e-6)


def test_the_ego_is_labelled_with_the_hud(recorded, env_params):
    """The ego's label at step t is the HUD of state t, the text the rendered frames
    show (one formatter: viewer.hud_glyphs, here on each reference state alone):
    step, speed, the action that led to state t ("-" at 0), TTC."""
    rrd, reference = recorded
    env, params = env_params
    hud = jax.jit(partial(viewer.hud_glyphs, static=env.static))
    for i, ref in enumerate(reference):
        labels = [row[0] for row in rrd[f"/episode/{i}/world/ego"]["Boxes2D:labels"]]
        assert len(labels) == len(ref["state"]) == len(ref["action"]) + 1
        for t, (label, state) in enumerate(zip(labels, ref["state"], strict=True)):
            assert label == viewer.hud_text(hud(state, params))
            action = "-" if t == 0 else ACTIONS[int(ref["action"][t - 1])]
            assert label.startswith(f"step {t}  ") and f" km/h  {action}  TTC " in label


def test_logged_steps_follow_the_episode_length(recorded):
    """Decisions at 0…L-1, the state after each of them at 1…L, nothing after the end."""
    rrd, reference = recorded
    for i, ref in enumerate(reference):
        length = len(ref["action"])
        root = f"/episode/{i}"
        np.testing.assert_array_equal(rrd[f"{root}/action"]["step"], np.arange(length))
        np.testing.assert_array_equal(scalars(rrd[f"{root}/action"]), ref["action"])
        np.testing.assert_array_equal(rrd[f"{root}/reward"]["step"], np.arange(1, length + 1))
        np.testing.assert_array_equal(scalars(rrd[f"{root}/reward"]), ref["reward"])
        speed = scalars(rrd[f"{root}/speed_kmh"])
        assert len(speed) == length + 1 and speed[0] == 0.0
        events = rrd[f"{root}/events"]
        texts = [row[0] for row in events["TextLog:text"]]
        struck = " · struck while stopped"
        expected = [
            ACTIONS[a] + (struck if hit else "")
            for a, hit in zip(ref["action"], ref["struck"], strict=True)
        ]
        assert texts[:length] == expected
        assert len(texts) == length + 1
        levels = [row[0] for row in events["TextLog:level"]]
        assert levels[:length] == ["WARN" if hit else "DEBUG" for hit in ref["struck"]]
        finite = np.isfinite(ref["ttc"])
        ttc = rrd[f"{root}/ttc"]  # finite values only; no temporal rows when none is
        np.testing.assert_array_equal(ttc.get("step", []), np.flatnonzero(finite) + 1)
        np.testing.assert_array_equal(scalars(ttc) if finite.any() else [], ref["ttc"][finite])


def test_a_pedestrian_striking_the_standing_car_is_a_warning(tmp_path, env_params, key):
    """SPEC §5: struck while stopped is no collision and ends nothing, but the
    events say so at its step, as a warning."""
    env, params = env_params
    record = episode_record.collect_episodes(drqn_jax.rule_based_agent(), key, 1, env, params)
    struck = np.zeros_like(np.asarray(record.struck_while_stopped))
    struck[0, 3] = True
    path = tmp_path / "struck.rrd"
    recording.write_episodes(
        path, dataclasses.replace(record, struck_while_stopped=struck), env, params
    )
    events = read_rrd(path)["/episode/0/events"]
    texts = [row[0] for row in events["TextLog:text"]]
    levels = [row[0] for row in events["TextLog:level"]]
    assert texts[3] == ACTIONS[int(record.action[0, 3])] + " · struck while stopped"
    assert levels[3] == "WARN" and levels[2] == levels[4] == "DEBUG"


def test_pedestrians_are_coloured_by_behaviour(recorded):
    rrd, reference = recorded
    palette = {code: recording.BEHAVIOUR_COLOURS[code] for code in range(len(BEHAVIOURS))}
    seen = set()
    for i, ref in enumerate(reference):
        peds = rrd[f"/episode/{i}/world/pedestrians"]
        behaviour = ref["peds"].behaviour
        positions = np.array(peds["Points2D:positions"], np.float32)
        np.testing.assert_array_equal(unflip(positions), ref["peds"].position)
        colours = np.array([[rgb(c) for c in row] for row in peds["Points2D:colors"]])
        expected = np.array([[palette[b] for b in row] for row in behaviour])
        np.testing.assert_array_equal(colours, expected)
        np.testing.assert_array_equal(np.array(peds["Points2D:class_ids"]), behaviour)
        arrows = rrd[f"/episode/{i}/world/headings"]
        vectors = unflip(np.array(arrows["Arrows2D:vectors"], np.float32))
        np.testing.assert_allclose(vectors, ref["peds"].velocity * 3.0, rtol=1e-6, atol=1e-7)
        seen |= set(np.unique(behaviour).tolist())
    assert len(seen) >= 2  # the colour check compared more than one behaviour
    (legend,) = rrd["/"]["static"]["AnnotationContext:context"]
    labels = {e["class_id"]: e["class_description"]["info"]["label"] for e in legend}
    assert labels == dict(enumerate(BEHAVIOURS))


def test_ttc_is_logged_where_finite(env_params, key, tmp_path):
    env, params = env_params
    agent = drqn_jax.rule_based_agent()
    record = episode_record.collect_episodes(agent, key, NUM_EPISODES, env, params)
    ttc = np.full_like(record.ttc, np.inf)
    ttc[0, [3, 7, MAX_STEPS - 1]] = [1.5, 0.0, 2.0]  # the last one lies after the episode's end
    length = np.full(NUM_EPISODES, MAX_STEPS - 1, np.int32)
    record = dataclasses.replace(record, ttc=ttc, length=length)
    recording.write_episodes(tmp_path / "ttc.rrd", record, env, params)
    entity = read_rrd(tmp_path / "ttc.rrd")["/episode/0/ttc"]
    np.testing.assert_array_equal(entity["step"], [4, 8])
    np.testing.assert_array_equal(scalars(entity), [1.5, 0.0])


def test_grid_channels_are_45_by_30_images(recorded):
    rrd, reference = recorded
    for i, ref in enumerate(reference):
        for c, name in enumerate(recording.GRID_CHANNELS):
            entity = rrd[f"/episode/{i}/grid/{name}"]
            (fmt,) = entity["static"]["Image:format"]
            assert (fmt["height"], fmt["width"]) == (45, 30)
            images = np.stack(
                [
                    np.array(row[0], np.uint8).view(np.float32).reshape(45, 30)
                    for row in entity["Image:buffer"]
                ]
            )
            np.testing.assert_array_equal(images, ref["grid"][..., c])


def test_q_values_of_the_drqn_equal_network_step(drqn):
    rrd, reference = drqn
    for i, ref in enumerate(reference):
        q = np.stack([scalars(rrd[f"/episode/{i}/q/{name}"]) for name in ACTIONS], axis=-1)
        # the recorded values come from one scan of vmapped steps, the reference from steps
        # jitted alone: XLA may round them differently (seen: 2e-6 relative)
        np.testing.assert_allclose(q, ref["q"], rtol=1e-5, atol=1e-6)
        # the agent acted on exactly these values, in the same compiled step
        np.testing.assert_array_equal(np.argmax(q, axis=-1), scalars(rrd[f"/episode/{i}/action"]))
        np.testing.assert_array_equal(np.argmax(q, axis=-1), ref["action"])
        names = [rrd[f"/episode/{i}/q/{name}"]["static"]["SeriesLines:names"] for name in ACTIONS]
        assert names == [[name] for name in ACTIONS]


def test_drqn_episode_is_bit_identical_alone_or_in_a_batch(env_params, key):
    """Episode 0 of a DRQN: the same Q-values to the bit alone and beside another, and
    the recorded episodes are the evaluated ones.

    The recording's decisions run in the evaluation's batches
    (``evaluation.map_episodes``: ``EVAL_BATCH`` rows; see tests/test_evaluation.py).
    """
    env, params = env_params
    network = make_network(SMALL_NET)
    weights = network.init(jax.random.key(3))
    agent = drqn_jax.drqn_agent(network, weights)

    def collect(n):
        return episode_record.collect_episodes(
            agent, key, n, env, params, network=network, network_params=weights
        )

    alone, together = collect(1), collect(NUM_EPISODES)
    np.testing.assert_array_equal(together.q_values[0], alone.q_values[0])
    np.testing.assert_array_equal(together.action[0], alone.action[0])
    evaluated = drqn_jax.evaluate(agent, key, NUM_EPISODES, env, params)["episodes"]
    np.testing.assert_array_equal(together.length, evaluated.length)
    np.testing.assert_array_equal(together.episode_return, evaluated.episode_return)


def test_rule_based_recording_has_no_q_values(rule_based):
    rrd, _ = rule_based
    assert not [entity for entity in rrd if "/q/" in entity]


def test_static_map_matches_the_semantic_map(rule_based, env_params):
    rrd, _ = rule_based
    env, params = env_params
    expected = {"/map/road": 3, "/map/walkways": 1, "/map/crosswalks": 2}
    for entity, semantic in expected.items():
        boxes = rrd[entity]
        assert set(boxes) == {"static"}  # no temporal rows
        centres = unflip(boxes["static"]["Boxes2D:centers"])
        assert len(centres) >= 3
        np.testing.assert_array_equal(semantic_class(centres, params, env.static), semantic)
    assert "/map/goal" in rrd and "/map/centre_line" in rrd


def test_training_curves_hold_one_value_per_episode(tmp_path):
    episodes = np.array([0, 1, 2, 4, 5, 7, 8])  # recorded out of order: gaps are possible
    n = len(episodes)
    collision = np.array([1, 0, 0, 1, 1, 0, 0], bool)
    metrics = {
        "episode": episodes,
        "episode_return": np.linspace(-10, 5, n, dtype=np.float32),
        "length": np.arange(10, 10 + n, dtype=np.int32),
        "collision": collision,
        "goal": ~collision,
        "distance": np.linspace(1, 50, n, dtype=np.float32),
        "mean_speed": np.full(n, 2.0, np.float32),
        "epsilon": np.linspace(1.0, 0.1, n, dtype=np.float32),
        "mean_loss": np.linspace(0.0, 1.0, n, dtype=np.float32),
    }
    path = tmp_path / "training.rrd"
    recording.record_training(path, metrics)
    rrd = read_rrd(path)
    curves = {
        "return": metrics["episode_return"],
        "length": metrics["length"],
        "loss": metrics["mean_loss"],
        "epsilon": metrics["epsilon"],
        "distance": metrics["distance"],
        "mean_speed_kmh": np.full(n, 7.2),
        "collision_rate": np.cumsum(collision) / np.arange(1, n + 1),  # n < window: all so far
        "goal_rate": np.cumsum(~collision) / np.arange(1, n + 1),
    }
    for name, values in curves.items():
        entity = rrd[f"/training/{name}"]
        np.testing.assert_array_equal(entity["episode"], episodes)
        np.testing.assert_allclose(scalars(entity), values, rtol=1e-6)
    window = recording.running_mean(np.arange(30) % 2, window=20)
    assert window[19] == 0.5 and window[25] == np.mean(np.arange(6, 26) % 2)
    with pytest.raises(ValueError, match="epsilon"):
        recording.record_training(path, {k: v for k, v in metrics.items() if k != "epsilon"})


def test_cli_replay_writes_a_readable_recording(tmp_path, capsys):
    out = tmp_path / "sub" / "episodes.rrd"
    args = ["replay", "--agent", "rule-based", "--config", "smoke", "--episodes", "2"]
    assert cli.main([*args, "--out", str(out)]) == 0
    rrd = read_rrd(out)
    config = load_config("smoke")
    env, params = config.make_env()
    _, eval_key = config.keys()
    evaluated = run_episodes(drqn_jax.rule_based_agent(), episode_keys(eval_key, 2), env, params)
    for i in range(2):
        length = int(evaluated.length[i])
        assert len(rrd[f"/episode/{i}/action"]["step"]) == length
        assert len(rrd[f"/episode/{i}/world/ego"]["step"]) == length + 1
    assert "/episode/2/world/ego" not in rrd
    assert str(out) in capsys.readouterr().out


def test_cli_replay_errors_are_one_line(tmp_path, capsys):
    assert cli.main(["replay", "--agent", "drqn", "--config", "smoke"]) == 2
    err = capsys.readouterr().err
    assert "RUN_DIR" in err and len(err.strip().splitlines()) == 1
    assert cli.main(["replay", "--config", "smoke", "--episodes", "0"]) == 2
    assert "--episodes" in capsys.readouterr().err
    assert cli.main(["replay", str(tmp_path / "nothing"), "--out", str(tmp_path / "x.rrd")]) == 2
    assert "not a run directory" in capsys.readouterr().err
    assert not (tmp_path / "x.rrd").exists()
