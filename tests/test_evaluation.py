"""Evaluation (drqn_jax/evaluation.py; SPEC §8): agents behind one interface run
through ``evaluate``, and the §8 metrics and intervals."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drqn_jax
from drqn_jax import evaluation
from drqn_jax.agents import RuleBasedParams
from drqn_jax.agents.shipped import shipped_agent_dir
from drqn_jax.env.state import ACCELERATE, BRAKE
from drqn_jax.evaluation import (
    EVAL_BATCH,
    EpisodeMetrics,
    episode_keys,
    run_episodes,
    wilson_interval,
)
from drqn_jax.experiments.runner import load_run, load_trained_network
from tests.helpers import assert_tree_equal, take

NUM = 48


@pytest.fixture(scope="module")
def results(env_params):
    env, params = env_params
    agents = {
        "rule": drqn_jax.rule_based_agent(),
        "random": drqn_jax.random_agent(),
        "accelerate": drqn_jax.constant_agent(ACCELERATE),
        "brake": drqn_jax.constant_agent(BRAKE),
    }
    return {
        name: drqn_jax.evaluate(agent, jax.random.key(123), NUM, env, params)
        for name, agent in agents.items()
    }


def test_wilson_interval_known_values():
    # Reference values (Wilson score, z = 1.96): 7/10 -> (0.3968, 0.8922)
    low, high = wilson_interval(7, 10)
    assert low == pytest.approx(0.39677, abs=1e-4) and high == pytest.approx(0.89222, abs=1e-4)
    low, high = wilson_interval(0, 20)
    assert low == 0.0 and high == pytest.approx(0.16113, abs=1e-4)
    low, high = wilson_interval(20, 20)
    assert high == 1.0 and low == pytest.approx(0.83887, abs=1e-4)


def test_metrics_fields_and_ranges(results):
    for name, res in results.items():
        assert res["num_episodes"] == NUM, name
        assert 0.0 <= res["collision_free_rate"] <= 1.0
        low, high = res["collision_free_ci"]
        assert low <= res["collision_free_rate"] <= high
        assert 0.0 <= res["goal_rate"] <= 1.0
        assert res["avg_speed_kmh"] >= 0.0
        ep = res["episodes"]
        assert ep.length.shape == (NUM,)
        assert np.all((ep.length >= 1) & (ep.length <= 1000))
        # an episode ends exactly once: goal/collision end it early, else 1000 steps
        ended_early = ep.collision | ep.goal
        assert np.all(ep.length[~ended_early] == 1000)
        assert np.all(ep.episode_return >= -10.0 * ep.length)
        assert np.all(ep.episode_return <= 1.0 * ep.length)


def test_agents_behave_as_named(results):
    brake, acc, rule = results["brake"], results["accelerate"], results["rule"]
    # always-brake never moves: no collision, no distance, stopped reward -1 every step
    assert brake["collision_free_rate"] == 1.0 and brake["avg_distance_m"] == 0.0
    assert brake["avg_return"] == -1000.0 and brake["goal_rate"] == 0.0
    # pedestrians that walk into the standing car strike it: no collision, no penalty
    assert np.all(brake["episodes"].moving_steps == 0)
    assert math.isnan(brake["avg_speed_authors_kmh"])  # no episode ever moved
    # the authors' speed leaves out the steps at a standstill (SPEC §8)
    for res in (acc, rule):
        assert res["avg_speed_authors_kmh"] >= res["avg_speed_kmh"]
    assert 10.0 < rule["avg_speed_authors_kmh"] < 16.0
    # always-accelerate is fast and reaches the goal unless it hits someone
    assert acc["avg_speed_kmh"] > 30.0
    ep = acc["episodes"]
    assert np.all(ep.goal | ep.collision)
    # the rule-based agent holds about 15 km/h when it can and never exceeds ~16 km/h
    assert 3.0 < rule["avg_speed_kmh"] < 16.0
    # it stands for pedestrians, who may walk into it (the paper's world): struck while
    # stopped, which always-accelerate, never standing after its first step, is not
    assert rule["struck_while_stopped_rate"] > 0.0 == acc["struck_while_stopped_rate"]
    assert brake["struck_while_stopped_rate"] >= rule["struck_while_stopped_rate"]


def test_summary_consistent_with_episodes(results):
    res = results["random"]
    ep = res["episodes"]
    free = ~ep.collision
    assert res["collision_free_rate"] == pytest.approx(free.mean())
    assert res["avg_distance_m"] == pytest.approx(ep.distance.astype(np.float64).mean())
    expected_speed = np.mean(ep.distance.astype(np.float64) / (ep.length * 0.1)) * 3.6
    assert res["avg_speed_kmh"] == pytest.approx(expected_speed, rel=1e-5)
    km = ep.distance.astype(np.float64).sum() / 1000
    if km > 0:
        assert res["collisions_per_km"] == pytest.approx(ep.collision.sum() / km)
    assert res["collision_free_ci"] == wilson_interval(int(free.sum()), NUM)
    assert res["struck_while_stopped_rate"] == pytest.approx(ep.struck_while_stopped.mean())
    # pooled over every moving step of every episode, as the authors' tester.py
    steps = ep.moving_steps.astype(np.float64)
    authors = (ep.authors_speed * steps).sum() / steps.sum() * 3.6
    assert res["avg_speed_authors_kmh"] == pytest.approx(authors)
    assert np.all(ep.moving_steps <= ep.length)


# The tests below run NUM episodes where they can: the programs of ``results``.


def test_episode_i_does_not_depend_on_num_episodes(env_params):
    env, params = env_params
    agent = drqn_jax.rule_based_agent()
    key = jax.random.key(5)
    big = run_episodes(agent, episode_keys(key, EVAL_BATCH + 20), env, params)  # two batches
    small = run_episodes(agent, episode_keys(key, 3), env, params)
    assert_tree_equal(take(big, slice(0, 3)), small)


def test_a_network_episode_does_not_depend_on_the_episodes_beside_it():
    """The shipped agent's first 24 episodes: the same bits among 24 or EVAL_BATCH + 40.
    XLA:CPU rounds its products and the env's sums by the rows of the program (YNNPACK's
    kernels below 61–81 rows, another switch near 470), and some of these episodes end
    differently in the last bits at 552 rows than at 128: every batch runs EVAL_BATCH."""
    directory = shipped_agent_dir("headline")
    config = load_run(directory)
    network, weights, _ = load_trained_network(config, directory)
    agent = drqn_jax.drqn_agent(network, weights)
    env, params = config.make_env()
    keys = episode_keys(jax.random.key(0), EVAL_BATCH + 40)
    few = run_episodes(agent, keys[:24], env, params)
    assert_tree_equal(take(run_episodes(agent, keys, env, params), slice(0, 24)), few)


def test_progress_reporting_evaluates_the_same_episodes(env_params, results, monkeypatch):
    """With a progress callback (host calls of EVAL_BATCH episodes, the last one padded):
    the same results, and a report after each call."""
    env, params = env_params
    monkeypatch.setattr(evaluation, "EVAL_BATCH", 20)
    done = []
    shown = drqn_jax.evaluate(
        drqn_jax.rule_based_agent(), jax.random.key(123), NUM, env, params, on_episodes=done.append
    )
    assert done == [20, 40, NUM]
    assert_tree_equal(shown["episodes"], results["rule"]["episodes"])
    assert shown["collision_free_rate"] == results["rule"]["collision_free_rate"]


def test_evaluate_is_deterministic_and_key_dependent(env_params, results):
    env, params = env_params
    agent = drqn_jax.random_agent()
    a = results["random"]  # key 123
    b = drqn_jax.evaluate(agent, jax.random.key(123), NUM, env, params)
    c = drqn_jax.evaluate(agent, jax.random.key(2), NUM, env, params)
    assert_tree_equal(a["episodes"], b["episodes"])
    assert not np.array_equal(a["episodes"].distance, c["episodes"].distance)


def test_rule_based_params_change_behaviour(env_params, results):
    env, params = env_params
    slow = drqn_jax.rule_based_agent(RuleBasedParams(v_max=5.0 / 3.6))
    res = drqn_jax.evaluate(slow, jax.random.key(123), NUM, env, params)
    assert res["avg_speed_kmh"] < 6.5 < results["rule"]["avg_speed_kmh"]
    with pytest.raises(ValueError, match="v_max"):
        RuleBasedParams(v_max=-1.0)


def test_invalid_arguments(env_params):
    env, params = env_params
    with pytest.raises(ValueError, match="num_episodes"):
        drqn_jax.evaluate(drqn_jax.random_agent(), jax.random.key(0), 0, env, params)
    with pytest.raises(ValueError, match="action"):
        drqn_jax.constant_agent(7)
    assert drqn_jax.constant_agent("brake").name == "always-brake"


def test_summarize_handles_no_finite_ttc():
    n = 4
    ep = EpisodeMetrics(
        episode_return=jnp.zeros(n),
        length=jnp.full(n, 10),
        collision=jnp.zeros(n, bool),
        goal=jnp.zeros(n, bool),
        distance=jnp.zeros(n),
        mean_speed=jnp.zeros(n),
        min_ttc=jnp.full(n, jnp.inf),
        near_collision_steps=jnp.zeros(n, jnp.int32),
        struck_while_stopped=jnp.zeros(n, bool),
        moving_steps=jnp.zeros(n, jnp.int32),
        authors_speed=jnp.zeros(n),
    )
    res = drqn_jax.summarize(ep)
    assert math.isnan(res["collisions_per_km"]) and math.isnan(res["min_ttc_mean_finite_s"])
    assert res["min_ttc_median_s"] == math.inf and res["near_collision_episode_rate"] == 0.0
    assert math.isnan(res["avg_speed_authors_kmh"]) and res["struck_while_stopped_rate"] == 0.0


def test_episodes_of_k_tick_decisions_are_measured_in_ticks():
    """With ``decision_steps = 5`` an episode's length, distance and mean speed are
    those of the ticks it played (SPEC §8), as a rollout of ``step_env`` counts them."""
    env, params = drqn_jax.make("UrbanPedestrians-v0", max_steps=40, decision_steps=5)
    agent, key = drqn_jax.constant_agent(ACCELERATE), jax.random.key(5)
    m = take(run_episodes(agent, key[None], env, params), 0)
    key_reset, _, key_run = jax.random.split(key, 3)
    _, state = env.reset(key_reset, params)
    step, ticks = jax.jit(env.step_env), 0
    for decision_key in jax.random.split(key_run, 8):
        _, key_env = jax.random.split(decision_key)
        _, state, _, terminated, truncated, info = step(key_env, state, ACCELERATE, params)
        ticks += int(info["ticks"]["played"].sum())
        if terminated or truncated:
            break
    assert int(m.length) == ticks == int(info["time"]) and 5 < ticks <= 40
    assert float(m.distance) == float(info["distance"]) > 0.0
    assert np.isclose(float(m.mean_speed), float(info["distance"]) / (ticks * params.dt))


def test_the_yardstick_decides_every_tick_in_any_world():
    """The rule-based agent and the planner play a k-tick world one tick per decision
    (SPEC §9: the frontier stays the strongest baseline): the same episodes as in
    the world with k = 1; a network-style agent's differ."""
    key = episode_keys(jax.random.key(9), 4)
    env1, params = drqn_jax.make("UrbanPedestrians-v0", max_steps=60)
    env5, _ = drqn_jax.make("UrbanPedestrians-v0", max_steps=60, decision_steps=5)
    rule = drqn_jax.rule_based_agent()
    assert rule.every_tick and not drqn_jax.random_agent().every_tick
    assert_tree_equal(run_episodes(rule, key, env5, params), run_episodes(rule, key, env1, params))
    accelerate = drqn_jax.constant_agent("accelerate")
    held = run_episodes(accelerate, key, env5, params)
    ticked = run_episodes(accelerate, key, env1, params)
    assert not np.array_equal(np.asarray(held.distance), np.asarray(ticked.distance))
