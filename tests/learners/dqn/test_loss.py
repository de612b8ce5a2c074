"""Double DQN targets and the sequence loss on hand-computed cases."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drqn_jax.env.state import Observation
from drqn_jax.learners.dqn.loss import (
    CLIP_GRAD,
    CLIP_HUBER,
    double_dqn_targets,
    huber,
    large_margin,
    n_step_targets,
    rescale,
    sequence_loss,
    unrescale,
)
from drqn_jax.learners.dqn.replay import Windows
from drqn_jax.learners.hyperparams import Hyperparams
from drqn_jax.learners.optim import adam, apply_updates, clip
from drqn_jax.networks import NetworkConfig, make_network
from tests.helpers import fast_jit, flat_random


def test_double_dqn_target_hand_computed():
    q_online_next = jnp.array([[1.0, 5.0, 2.0, 0.0], [3.0, 0.0, 0.0, 1.0], [0.0, 0.0, 9.0, 0.0]])
    q_target_next = jnp.array([[7.0, 2.0, 8.0, 9.0], [4.0, 6.0, 6.0, 6.0], [1.0, 1.0, -3.0, 1.0]])
    reward = jnp.array([1.0, -1.0, 0.5])
    # step 0: ordinary; step 1: terminal (no bootstrap); step 2: truncated — it is
    # not terminated, so it bootstraps
    terminated = jnp.array([False, True, False])
    y = double_dqn_targets(q_online_next, q_target_next, reward, terminated, 0.9)
    # argmax online -> [1, 0, 2]; target at those -> [2, 4, -3]
    np.testing.assert_allclose(np.asarray(y), [1.0 + 0.9 * 2.0, -1.0, 0.5 + 0.9 * -3.0])
    # not plain DQN: max of the target would give 1 + 0.9·9 for step 0
    assert float(y[0]) != pytest.approx(1.0 + 0.9 * 9.0)


def _n_step_reference(q_online_next, q_target_next, reward, terminated, mask, gamma, n):
    """n-step Double DQN targets by hand, in float64: sum rewards until n steps, the
    episode's end (termination or the last real step) or the window's end."""
    steps, batch = reward.shape
    y = np.zeros((steps, batch))
    for b in range(batch):
        for t in range(steps):
            if not mask[t, b]:
                continue
            ret, discount, j, done = 0.0, 1.0, t, False
            while j < steps and j < t + n and mask[j, b]:
                ret += discount * reward[j, b]
                discount *= gamma
                j += 1
                if terminated[j - 1, b]:
                    done = True
                    break
            # observation j is q[..][j - 1]
            a_star = np.argmax(q_online_next[j - 1, b])
            y[t, b] = ret + (0.0 if done else discount * q_target_next[j - 1, b, a_star])
    return y


def test_n_step_targets_match_hand_computation():
    """Windows of 6 steps: b0 runs to the window's end, b1 terminates at step 3,
    b2 is truncated after step 2 (not terminated: it bootstraps), b3 terminates at
    step 0; after an episode's end comes padding with garbage rewards."""
    rng = np.random.default_rng(0)
    steps, batch = 6, 4
    q_online_next = rng.normal(size=(steps, batch, 4)).astype(np.float32)
    q_target_next = rng.normal(size=(steps, batch, 4)).astype(np.float32)
    reward = rng.normal(size=(steps, batch)).astype(np.float32)
    length = np.array([6, 4, 3, 1])
    mask = np.arange(steps)[:, None] < length
    terminated = np.zeros((steps, batch), bool)
    terminated[3, 1] = terminated[0, 3] = True
    args = [jnp.asarray(x) for x in (q_online_next, q_target_next, reward, terminated, mask)]
    for n in (1, 2, 3, 6):
        y = np.asarray(n_step_targets(*args, 0.9, n))
        ref = _n_step_reference(q_online_next, q_target_next, reward, terminated, mask, 0.9, n)
        np.testing.assert_allclose(y[mask], ref[mask], rtol=1e-5, atol=1e-6, err_msg=f"n={n}")
        assert np.all(np.isfinite(y))
    # n = 1 is the paper's one-step target, bit for bit
    np.testing.assert_array_equal(
        np.asarray(n_step_targets(*args, 0.9, 1)),
        np.asarray(double_dqn_targets(*args[:4], 0.9)),
    )
    # spot checks: b3 terminates at once, so its target is its reward for any n;
    # b2's last real step bootstraps from observation 3 with γ
    y3 = np.asarray(n_step_targets(*args, 0.9, 3))
    assert y3[0, 3] == pytest.approx(reward[0, 3])
    a_star = np.argmax(q_online_next[2, 2])
    assert y3[2, 2] == pytest.approx(reward[2, 2] + 0.9 * q_target_next[2, 2, a_star], rel=1e-6)
    # n-step differs from one-step where more than one real step lies ahead
    assert not np.allclose(y3[0, 0], np.asarray(n_step_targets(*args, 0.9, 1))[0, 0])


def _h(x, eps=1e-3):
    return np.sign(x) * (np.sqrt(np.abs(x) + 1.0) - 1.0) + eps * x


def test_value_rescaling_and_its_inverse():
    """R2D2's h(x) = sign(x)(√(|x| + 1) − 1) + εx and h⁻¹, in float32, against float64."""
    x = np.array([-1000.0, -100.0, -10.0, -1.0, -0.01, 0.0, 0.01, 1.0, 3.0, 100.0], np.float32)
    np.testing.assert_allclose(
        np.asarray(rescale(jnp.asarray(x))), _h(x.astype(np.float64)), rtol=1e-6
    )
    back = np.asarray(unrescale(rescale(jnp.asarray(x))))
    np.testing.assert_allclose(back, x, rtol=2e-5, atol=1e-5)
    assert float(rescale(jnp.float32(-100.0))) == pytest.approx(-9.15, abs=0.01)  # −100 shrinks


def test_value_rescaled_n_step_targets_match_hand_computation():
    """``value_rescale = 1``: y = h(Σ γ^k r + γ^m h⁻¹(Q_target(s', a*))), a* by the
    online values (h is increasing, so the argmax is the same either way); 0 is the
    paper's target bit for bit."""
    rng = np.random.default_rng(1)
    steps, batch = 5, 3
    q_online_next = rng.normal(size=(steps, batch, 4)).astype(np.float32)
    q_target_next = (3.0 * rng.normal(size=(steps, batch, 4))).astype(np.float32)
    reward = rng.normal(size=(steps, batch)).astype(np.float32) * 10.0
    mask = np.arange(steps)[:, None] < np.array([5, 3, 2])
    terminated = np.zeros((steps, batch), bool)
    terminated[2, 1] = True
    args = [jnp.asarray(x) for x in (q_online_next, q_target_next, reward, terminated, mask)]
    q64 = q_target_next.astype(np.float64)
    q_unscaled = np.asarray(unrescale(jnp.asarray(q_target_next)), np.float64)
    np.testing.assert_allclose(_h(q_unscaled), q64, rtol=1e-5, atol=1e-5)
    for n in (1, 3):
        y = np.asarray(n_step_targets(*args, 0.9, n, value_rescale=1))
        ref = _h(_n_step_reference(q_online_next, q_unscaled, reward, terminated, mask, 0.9, n))
        np.testing.assert_allclose(y[mask], ref[mask], rtol=1e-5, atol=1e-5, err_msg=f"n={n}")
        plain = np.asarray(n_step_targets(*args, 0.9, n))
        np.testing.assert_array_equal(plain, np.asarray(n_step_targets(*args, 0.9, n, 0)))
        assert not np.allclose(plain[mask], y[mask])


def test_huber():
    x = jnp.array([-3.0, -1.0, -0.5, 0.0, 0.5, 1.0, 3.0])
    np.testing.assert_allclose(np.asarray(huber(x)), [2.5, 0.5, 0.125, 0.0, 0.125, 0.5, 2.5])
    g = jax.grad(lambda x: jnp.sum(huber(x)))(x)
    np.testing.assert_allclose(np.asarray(g), [-1.0, -1.0, -0.5, 0.0, 0.5, 1.0, 1.0])


@pytest.fixture(scope="module")
def small_net():
    net = make_network(NetworkConfig(recurrent=16, hidden=16, scan_unroll=1))
    return net, net.init(jax.random.key(0)), net.init(jax.random.key(1))


def _sequence_loss(online, target, windows, net, clip_mode=CLIP_HUBER, n_step=1):
    """``sequence_loss`` at γ = 0.9."""
    return sequence_loss(
        online, target, windows, net, Hyperparams(gamma=0.9, clip=clip_mode), n_step
    )


#: ``_sequence_loss`` as one program per network and window shape, which the tests
#: share (op by op, each call compiles hundreds of small programs).
_td_loss = fast_jit(_sequence_loss, static_argnums=(3, 5))

#: The gradients of ``_td_loss`` with respect to the online and the target parameters.
_td_grads = fast_jit(
    jax.grad(lambda *args: _sequence_loss(*args)[0], argnums=(0, 1)), static_argnums=(3, 5)
)


@functools.partial(fast_jit, static_argnums=0)
def _unroll(net, params, obs):
    """The network's Q-values over a window from the initial carry, no resets."""
    batch = obs.speed.shape[1:]
    return net.unroll(params, obs, net.initial_carry(batch), jnp.zeros(obs.speed.shape, bool))[0]


def _windows(key, steps=4, batch=3, mask=None):
    k1, k2, k3, k4 = jax.random.split(key, 4)
    obs = Observation(
        grid=flat_random(jax.random.uniform, k1, (steps + 1, batch, 45, 30, 4)),
        speed=flat_random(jax.random.uniform, k2, (steps + 1, batch)),
        last_action=flat_random(jax.random.randint, k3, (steps + 1, batch), -1, 4),
    )
    mask = jnp.ones((steps, batch), bool) if mask is None else mask
    return Windows(
        obs=obs,
        records=None,
        action=flat_random(jax.random.randint, k4, (steps, batch), 0, 4),
        reward=jnp.where(mask, jnp.linspace(-1, 1, steps * batch).reshape(steps, batch), 0.0),
        terminated=jnp.zeros((steps, batch), bool).at[-1, 0].set(True) & mask,
        mask=mask,
        slot=jnp.zeros((batch,), jnp.int32),
        start=jnp.zeros((batch,), jnp.int32),
        resets=jnp.zeros((steps + 1, batch), bool),
    )


def test_sequence_loss_matches_hand_unrolled(small_net):
    net, online, target = small_net
    w = _windows(jax.random.key(2))
    loss, _ = _td_loss(online, target, w, net)
    q_on, q_tg = _unroll(net, online, w.obs), _unroll(net, target, w.obs)
    q_on, q_tg = np.asarray(q_on, np.float64), np.asarray(q_tg, np.float64)
    total = 0.0
    for t in range(4):
        for b in range(3):
            a_star = np.argmax(q_on[t + 1, b])
            boot = 0.0 if bool(w.terminated[t, b]) else 0.9 * q_tg[t + 1, b, a_star]
            td = q_on[t, b, int(w.action[t, b])] - (float(w.reward[t, b]) + boot)
            total += 0.5 * td**2 if abs(td) <= 1 else abs(td) - 0.5
    assert float(loss) == pytest.approx(total / 12, rel=1e-5)


def test_n_step_sequence_loss_matches_hand_unrolled(small_net):
    net, online, target = small_net
    mask = jnp.ones((4, 3), bool).at[3:, 1].set(False).at[2:, 2].set(False)
    w = _windows(jax.random.key(5), mask=mask)
    loss, _ = _td_loss(online, target, w, net, CLIP_HUBER, 3)
    q_on, q_tg = _unroll(net, online, w.obs), _unroll(net, target, w.obs)
    q_on, q_tg = np.asarray(q_on, np.float64), np.asarray(q_tg, np.float64)
    m = np.asarray(w.mask)
    y = _n_step_reference(
        q_on[1:], q_tg[1:], np.asarray(w.reward), np.asarray(w.terminated), m, 0.9, 3
    )
    q_taken = np.take_along_axis(q_on[:-1], np.asarray(w.action)[..., None], -1)[..., 0]
    td = (q_taken - y)[m]
    per_step = np.where(np.abs(td) <= 1, 0.5 * td**2, np.abs(td) - 0.5)
    assert float(loss) == pytest.approx(per_step.mean(), rel=1e-5)
    one_step, _ = _td_loss(online, target, w, net)
    assert float(loss) != pytest.approx(float(one_step), rel=1e-5)


def test_padding_is_masked_out(small_net):
    net, online, target = small_net
    mask = jnp.ones((4, 3), bool).at[2:, 1].set(False)
    w = _windows(jax.random.key(3), mask=mask)
    loss, _ = _td_loss(online, target, w, net)
    # garbage in the padded steps changes nothing
    garbage = w.replace(
        action=w.action.at[2:, 1].set(3),
        obs=w.obs.replace(grid=w.obs.grid.at[3:, 1].set(7.0)),
    )
    loss_g, _ = _td_loss(online, target, garbage, net)
    assert float(loss) == float(loss_g)
    grads, _ = _td_grads(online, target, garbage, net)
    grads_ref, _ = _td_grads(online, target, w, net)
    for a, b in zip(jax.tree.leaves(grads), jax.tree.leaves(grads_ref), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_burn_in_warms_the_lstm_without_loss_or_gradient(small_net):
    """R2D2's burn-in: the first L steps of the windows only warm the LSTM. The loss
    is the same number as unrolling them with the rest (they are masked), but no
    gradient flows into them: the burn-in observations get none, the others do."""
    net, online, target = small_net
    burn, steps = 3, 4
    mask = jnp.ones((burn + steps, 3), bool).at[:burn].set(False)
    w = _windows(jax.random.key(5), steps=burn + steps, mask=mask)

    def loss_of(grid, burn_in):
        obs = w.obs.replace(grid=grid)
        hp = Hyperparams(gamma=0.9)
        return sequence_loss(online, target, w.replace(obs=obs), net, hp, burn_in=burn_in)[0]

    # jitted, one program per burn-in: op by op, each unroll's scan compiles anew
    loss_and_grad = fast_jit(jax.value_and_grad(loss_of), static_argnums=1)
    with_burn, g_burn = loss_and_grad(w.obs.grid, burn)
    through, g_through = loss_and_grad(w.obs.grid, 0)
    assert float(with_burn) == pytest.approx(float(through), rel=1e-6)
    g_burn, g_through = np.asarray(g_burn), np.asarray(g_through)
    assert not g_burn[:burn].any() and g_burn[burn:].any()
    assert np.abs(g_through[:burn]).sum() > 0  # without the cut, gradients reach them


def test_gradients_flow_only_to_online_and_grad_mode(small_net):
    net, online, target = small_net
    w = _windows(jax.random.key(4))
    _, g_target = _td_grads(online, target, w, net)
    assert all(float(jnp.abs(x).max()) == 0.0 for x in jax.tree.leaves(g_target))
    # MSE mode: the loss is ½δ², its clamped gradient is in [-1, 1]
    loss_mse, aux = _td_loss(online, target, w, net, CLIP_GRAD)
    loss_huber, _ = _td_loss(online, target, w, net, CLIP_HUBER)
    assert float(loss_mse) >= float(loss_huber)
    g, _ = _td_grads(online, target, w, net, CLIP_GRAD)
    clamped = clip(g, 1.0)
    assert all(float(jnp.abs(x).max()) <= 1.0 for x in jax.tree.leaves(clamped))
    assert float(aux["td_abs"]) > 0.0


def test_large_margin_hand_computed():
    q = jnp.array([[1.0, 3.0, 2.0, 0.0], [1.0, 3.0, 2.0, 0.0], [5.0, 3.0, 4.5, 0.0]])
    expert = jnp.array([0, 1, 0])
    # max_a [Q(a) + l·1(a ≠ a_E)] − Q(a_E), l = 1: max(1, 4, 3, 1) − 1; max(2, 3, 3, 1) − 3;
    # max(5, 4, 5.5, 1) − 5 (a lead smaller than the margin still costs)
    np.testing.assert_allclose(np.asarray(large_margin(q, expert, 1.0)), [3.0, 0.0, 0.5])
    assert float(large_margin(q, expert, 0.25)[2]) == 0.0


def test_imitation_term_adds_the_weighted_margin_and_teaches_the_expert(small_net):
    """The imitation term is the mean of w_t · J_E(t) over the masked steps, added to
    the TD loss (zero weight: the TD loss exactly); minimising it makes the expert's
    action the greedy one where w_t > 0."""
    net, online, target = small_net
    mask = jnp.ones((4, 3), bool).at[3:, 1].set(False)
    w = _windows(jax.random.key(6), mask=mask)
    expert = jax.random.randint(jax.random.key(7), (4, 3), 0, 4)
    weight = jnp.where(jnp.arange(3) == 2, 0.0, 2.0)[None, :] * jnp.ones((4, 1))
    hp = Hyperparams(gamma=0.9, clip=CLIP_GRAD, imitation_margin=1.0)
    td_loss, _ = sequence_loss(online, target, w, net, hp)
    zero, _ = sequence_loss(online, target, w, net, hp, 1, expert, weight * 0)
    assert float(zero) == float(td_loss)
    loss, aux = sequence_loss(online, target, w, net, hp, 1, expert, weight)
    q = np.asarray(_unroll(net, online, w.obs)[:-1], np.float64)
    q_expert = np.take_along_axis(q, np.asarray(expert)[..., None], -1)[..., 0]
    other = np.arange(4) != np.asarray(expert)[..., None]
    j_e = (q + 1.0 * other).max(-1) - q_expert
    m = np.asarray(mask)
    expected = (np.asarray(weight) * j_e)[m].sum() / m.sum()
    assert float(aux["margin"]) == pytest.approx(expected, rel=1e-5)
    assert float(loss) == pytest.approx(float(td_loss) + expected, rel=1e-5)

    opt, hp = adam(1e-2), hp.replace(gamma=0.0)

    @fast_jit
    def step(params, opt_state):
        grads = jax.grad(lambda p: sequence_loss(p, target, w, net, hp, 1, expert, weight * 50)[0])(
            params
        )
        updates, opt_state = opt.update(grads, opt_state, params)
        return apply_updates(params, updates), opt_state

    params, opt_state = online, opt.init(online)
    for _ in range(200):
        params, opt_state = step(params, opt_state)
    greedy = np.asarray(jnp.argmax(_unroll(net, params, w.obs)[:-1], -1))
    taught = m & (np.asarray(weight) > 0)
    np.testing.assert_array_equal(greedy[taught], np.asarray(expert)[taught])
