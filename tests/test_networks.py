"""The Q-network of Table I: shapes, parameter count, the forget bias, step ≡ unroll."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.state import Observation
from drqn_jax.layers import gru_cell
from drqn_jax.networks import NetworkConfig, conv_torso, make_network
from tests.helpers import fast_jit, flat_random


@pytest.fixture(scope="module")
def drqn():
    net = make_network()
    return net, net.init(jax.random.key(0))


def _obs(key, lead):
    k1, k2, k3 = jax.random.split(key, 3)
    return Observation(
        grid=flat_random(jax.random.uniform, k1, (*lead, 45, 30, 4)),
        speed=flat_random(jax.random.uniform, k2, lead),
        last_action=flat_random(jax.random.randint, k3, lead, -1, 4),
    )


def test_conv_stack_reaches_1x1x64(drqn):
    net, params = drqn
    assert net.config.conv_output_shape == (1, 1, 64)
    grid = jax.ShapeDtypeStruct((3, 45, 30, 4), jnp.float32)  # shapes alone: not compiled
    assert jax.eval_shape(lambda g: conv_torso(params, g, net.config), grid).shape == (3, 64)
    # 45×30 → 10×7 → 3×2 → 1×1, layer by layer
    x = grid
    shapes = []
    for layer, (_, _, stride, _) in zip(params["conv"], net.config.conv, strict=True):
        x = jax.eval_shape(
            lambda x, w, s=stride: jax.lax.conv_general_dilated(
                x, w, (s, s), "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC")
            ),
            x,
            layer["w"],
        )
        shapes.append(x.shape[1:])
    assert shapes == [(10, 7, 32), (3, 2, 64), (1, 1, 64)]


def test_parameter_count(drqn):
    _, params = drqn
    conv = (8 * 6 * 4 * 32 + 32) + (4 * 3 * 32 * 64 + 64) + (2 * 2 * 64 * 64 + 64)
    lstm1 = (64 + 256) * 4 * 256 + 4 * 256
    lstm2 = (256 + 1 + 4 + 256) * 4 * 256 + 4 * 256
    head = (256 * 256 + 256) + (256 * 4 + 4)
    assert sum(x.size for x in jax.tree.leaves(params)) == conv + lstm1 + lstm2 + head == 973_220


def test_forget_bias_is_one(drqn):
    _, params = drqn
    b = np.asarray(params["lstm1"]["b"]).reshape(4, 256)
    assert np.all(b[1] == 1.0) and np.all(b[[0, 2, 3]] == 0.0)


def test_step_shapes_single_and_batched(drqn):
    net, params = drqn  # shapes alone: traced, not compiled
    q, carry = jax.eval_shape(net.step, params, _obs(jax.random.key(1), ()), net.initial_carry())
    assert q.shape == (4,) and carry[1][0].shape == (256,)
    batched = (_obs(jax.random.key(1), (7,)), net.initial_carry((7,)))
    q, carry = jax.eval_shape(net.step, params, *batched)
    assert q.shape == (7, 4) and carry[0][1].shape == (7, 256)


def test_unroll_equals_repeated_steps_with_resets(drqn):
    net, params = drqn
    steps, batch = 6, 3
    obs = _obs(jax.random.key(2), (steps, batch))
    resets = jnp.zeros((steps, batch), bool).at[3, 1].set(True)  # env 1 restarts at t = 3
    q_seq, _final = fast_jit(net.unroll)(params, obs, net.initial_carry((batch,)), resets)
    carry = net.initial_carry((batch,))
    step = fast_jit(net.step)
    for t in range(steps):
        carry = jax.tree.map(lambda x, t=t: jnp.where(resets[t][:, None], 0.0, x), carry)
        q, carry = step(params, jax.tree.map(lambda x, t=t: x[t], obs), carry)
        np.testing.assert_allclose(np.asarray(q_seq[t]), np.asarray(q), rtol=1e-5, atol=1e-6)
    # the reset really changes env 1 from t = 3 on, and nothing else
    q_nr, _ = fast_jit(net.unroll)(
        params, obs, net.initial_carry((batch,)), jnp.zeros((steps, batch), bool)
    )
    assert np.array_equal(np.asarray(q_nr[:3]), np.asarray(q_seq[:3]))
    assert not np.allclose(np.asarray(q_nr[3:, 1]), np.asarray(q_seq[3:, 1]))
    assert np.array_equal(np.asarray(q_nr[:, 0]), np.asarray(q_seq[:, 0]))


def test_memory_matters_for_drqn_not_dqn():
    """The LSTM carries information across steps; the DQN variant does not."""
    obs = _obs(jax.random.key(3), (4, 1))
    other_first = obs.replace(grid=obs.grid.at[0].set(0.0))
    for kind, remembers in (("drqn", True), ("dqn", False)):
        net = make_network(NetworkConfig(kind=kind, recurrent=32, hidden=32))
        params = net.init(jax.random.key(0))
        resets = jnp.zeros((4, 1), bool)
        unroll = fast_jit(net.unroll)  # one program for both sequences
        q_a, _ = unroll(params, obs, net.initial_carry((1,)), resets)
        q_b, _ = unroll(params, other_first, net.initial_carry((1,)), resets)
        changed_later = not np.allclose(np.asarray(q_a[3]), np.asarray(q_b[3]))
        assert changed_later == remembers, kind
        assert net.initial_carry((1,)) == () if kind == "dqn" else True


def test_gru_cell_is_flaxs_gru_cell():
    """The "gru" cell: our weights laid out as flax's ``GRUCell`` (purejaxql's cell)
    give its outputs; the network names its layers gru1 and gru2 and its carry is
    one state per layer."""
    import flax.linen as nn

    n_in, width, batch = 3, 5, 4
    p = make_network(
        NetworkConfig(torso="mlp", obs_size=n_in, mlp=(n_in,), recurrent=width, cell="gru")
    ).init(jax.random.key(0))
    assert {"gru1", "gru2"} <= set(p) and "lstm1" not in p
    cell = p["gru1"]
    cell = {**cell, "b": jax.random.normal(jax.random.key(1), cell["b"].shape)}
    cell["b_hn"] = jax.random.normal(jax.random.key(2), cell["b_hn"].shape)
    x = jax.random.normal(jax.random.key(3), (batch, n_in))
    h = jax.random.normal(jax.random.key(4), (batch, width))
    w_x, w_h = cell["w"][:n_in], cell["w"][n_in:]
    b_r, b_z, b_n = jnp.split(cell["b"], 3)
    wx_r, wx_z, wx_n = jnp.split(w_x, 3, axis=-1)
    wh_r, wh_z, wh_n = jnp.split(w_h, 3, axis=-1)
    flax_params = {
        "ir": {"kernel": wx_r, "bias": b_r},
        "iz": {"kernel": wx_z, "bias": b_z},
        "in": {"kernel": wx_n, "bias": b_n},
        "hr": {"kernel": wh_r},
        "hz": {"kernel": wh_z},
        "hn": {"kernel": wh_n, "bias": cell["b_hn"]},
    }
    want, _ = nn.GRUCell(width).apply({"params": flax_params}, h, x)
    got, (state,) = gru_cell(cell, x, (h,))
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-5, atol=1e-6)
    assert np.array_equal(np.asarray(state), np.asarray(got))


def test_mlp_torso_for_flat_observations():
    """torso = "mlp" (a gymnax env's flat vector): the torso's dense layers feed the
    same core and head, with no speed or last-action inputs; the DRQN's unroll is
    its steps with resets, and its LSTMs (or GRUs) remember what the DQN's dense
    core forgets."""
    obs = jax.random.normal(jax.random.key(4), (5, 2, 3))
    resets = jnp.zeros((5, 2), bool).at[2, 0].set(True)
    for kind, cell in (("drqn", "lstm"), ("drqn", "gru"), ("dqn", "lstm")):
        config = NetworkConfig(
            kind=kind,
            torso="mlp",
            obs_size=3,
            mlp=(16, 8),
            recurrent=8,
            hidden=8,
            num_actions=2,
            cell=cell,
        )
        net = make_network(config)
        params = net.init(jax.random.key(0))
        assert [layer["w"].shape for layer in params["torso"]] == [(3, 16), (16, 8)]
        assert "conv" not in params and config.extra_inputs == 0
        unroll, step = fast_jit(net.unroll), fast_jit(net.step)  # a program each, not op by op
        q_seq, _ = unroll(params, obs, net.initial_carry((2,)), resets)
        carry = net.initial_carry((2,))
        for t in range(5):
            carry = jax.tree.map(lambda x, t=t: jnp.where(resets[t][:, None], 0.0, x), carry)
            q, carry = step(params, obs[t], carry)
            np.testing.assert_allclose(np.asarray(q_seq[t]), np.asarray(q), rtol=1e-5, atol=1e-6)
        other = obs.at[0].set(0.0)
        q_other, _ = unroll(params, other, net.initial_carry((2,)), jnp.zeros((5, 2), bool))
        q_same, _ = unroll(params, obs, net.initial_carry((2,)), jnp.zeros((5, 2), bool))
        assert (not np.allclose(q_other[1], q_same[1])) == (kind == "drqn"), kind
    with pytest.raises(ValueError, match="obs_size"):
        NetworkConfig(torso="mlp", obs_size=0)
    with pytest.raises(ValueError, match="cell = 'rnn': must be one of"):
        NetworkConfig(cell="rnn")
    with pytest.raises(ValueError, match="a cell is for kind 'drqn'"):
        NetworkConfig(kind="dqn", cell="gru")
    with pytest.raises(ValueError, match="torso"):
        NetworkConfig(torso="transformer")


STACKED = NetworkConfig(kind="dqn", recurrent=32, hidden=32, frames=3)


def test_frame_stacking_dqn_sees_the_last_grids_and_restarts_with_the_episode():
    """``frames`` = k: the DQN's input is its last k grids (zeros before an episode's
    start). unroll ≡ repeated steps, with a reset; the grid 2 steps back changes the
    Q-values, the grid 3 steps back does not; k = 1 keeps the memoryless DQN."""
    net = make_network(STACKED)
    params = net.init(jax.random.key(0))
    assert params["conv"][0]["w"].shape[2] == 3 * 4
    steps, batch = 6, 2
    obs = _obs(jax.random.key(4), (steps, batch))
    resets = jnp.zeros((steps, batch), bool).at[3, 1].set(True)
    unroll = fast_jit(net.unroll)  # one program for every unroll below (op by op: hundreds)
    q_seq, final = unroll(params, obs, net.initial_carry((batch,)), resets)
    carry, step = net.initial_carry((batch,)), fast_jit(net.step)
    assert carry.shape == (batch, 2, 45, 30, 4)
    for t in range(steps):
        carry = jnp.where(resets[t][:, None, None, None, None], 0.0, carry)
        q, carry = step(params, jax.tree.map(lambda x, t=t: x[t], obs), carry)
        np.testing.assert_allclose(np.asarray(q_seq[t]), np.asarray(q), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(final), np.asarray(carry))
    # env 1 restarted at t = 3: its grids before are gone from steps 3 and 4
    no_reset = jnp.zeros((steps, batch), bool)
    changed = obs.replace(grid=obs.grid.at[1, 1].set(0.0).at[2, 1].set(0.0))
    q_changed, _ = unroll(params, changed, net.initial_carry((batch,)), resets)
    np.testing.assert_array_equal(np.asarray(q_changed[3:, 1]), np.asarray(q_seq[3:, 1]))
    q_a, _ = unroll(params, obs, net.initial_carry((batch,)), no_reset)
    q_changed, _ = unroll(params, changed, net.initial_carry((batch,)), no_reset)
    assert not np.allclose(np.asarray(q_changed[3, 1]), np.asarray(q_a[3, 1]))
    # without a reset, zeroing the grids before is the reset: the same stack
    np.testing.assert_array_equal(np.asarray(q_changed[3, 1]), np.asarray(q_seq[3, 1]))
    # the window is k grids: grid 0 reaches steps 0-2, not step 3
    zero_first = obs.replace(grid=obs.grid.at[0].set(0.0))
    q_b, _ = unroll(params, zero_first, net.initial_carry((batch,)), no_reset)
    assert not np.allclose(np.asarray(q_a[2]), np.asarray(q_b[2]))
    np.testing.assert_array_equal(np.asarray(q_a[3:]), np.asarray(q_b[3:]))
    with pytest.raises(ValueError, match="frames = 2: stacking grids is for kind 'dqn'"):
        NetworkConfig(kind="drqn", frames=2)


def test_config_validation():
    with pytest.raises(ValueError, match="kind"):
        NetworkConfig(kind="transformer")
    with pytest.raises(ValueError, match="shrinks to nothing"):
        NetworkConfig(grid_shape=(30, 45, 4)).conv_output_shape  # noqa: B018
    with pytest.raises(ValueError, match="recurrent"):
        NetworkConfig(recurrent=0)
