"""Check that an environment keeps the gymnax 1.0 contract (ours, or a user's).
:func:`check_env_contract` runs a short random rollout of a few envs (``jit`` and ``vmap``) and
raises :class:`EnvContractError` naming the first broken rule: gymnax 1.0 ``reset``/``step``
signatures, shapes and dtypes; finite observations inside ``observation_space``, finite rewards;
same-step auto-reset to ``reset(reset_key(step_key))`` (``info["final_observation"]`` is ``obs``
while the episode goes on); same keys, same bits; ``jit`` ≡ op by op for the first ``eager_steps``
steps. Auto-reset is only checked where an episode ends: use a small ``max_steps`` (e.g. 16)."""

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from drqn_jax.programs import jit_in_store


class EnvContractError(AssertionError):
    """An environment broke the contract :func:`check_env_contract` checks."""


def _fail(message: str) -> None:
    raise EnvContractError(message)


class ContractReport(NamedTuple):
    """What :func:`check_env_contract` ran and saw; ``resets``: steps that ended an
    episode (auto-reset checked there)."""

    num_envs: int
    num_steps: int
    terminations: int
    truncations: int
    resets: int
    reward_min: float
    reward_max: float


def same_key(key: jax.Array) -> jax.Array:
    """The key a ``drqn_jax`` env's auto-reset uses: the step's own key."""
    return key


def _is_key(x: Any) -> bool:
    return hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jax.dtypes.prng_key)


def _plain(tree: Any) -> Any:
    """Typed PRNG keys as their uint32 data, so every leaf compares as numbers."""
    return jax.tree.map(lambda x: jax.random.key_data(x) if _is_key(x) else x, tree)


def _tree_equal_traced(a: Any, b: Any) -> jax.Array:
    """() bool: every leaf of ``a`` equals ``b``'s, NaN equal to NaN (inside ``jit``)."""

    def leaf(x, y):
        x, y = jnp.asarray(x), jnp.asarray(y)
        same = x == y
        if jnp.issubdtype(x.dtype, jnp.inexact):
            same = same | (jnp.isnan(x) & jnp.isnan(y))
        return jnp.all(same)

    return jnp.all(jnp.asarray(jax.tree.leaves(jax.tree.map(leaf, _plain(a), _plain(b))), bool))


def _all_finite(tree: Any) -> jax.Array:
    """() bool: every floating leaf of ``tree`` is finite."""
    leaves = [x for x in jax.tree.leaves(_plain(tree)) if jnp.issubdtype(x.dtype, jnp.inexact)]
    return jnp.all(jnp.asarray([jnp.all(jnp.isfinite(x)) for x in leaves], bool))


def _check_same_types(what: str, got: Any, want: Any) -> None:
    if jax.tree.structure(got) != jax.tree.structure(want):
        _fail(
            f"{what}: the step's tree structure {jax.tree.structure(got)} is not the "
            f"reset's {jax.tree.structure(want)}"
        )
    leaves = jax.tree_util.tree_leaves_with_path(got)
    for (path, g), w in zip(leaves, jax.tree.leaves(want), strict=True):
        if (g.shape, g.dtype) != (w.shape, w.dtype):
            _fail(
                f"{what}{jax.tree_util.keystr(path)}: the step returns {g.dtype}"
                f"{list(g.shape)}, the reset {w.dtype}{list(w.shape)}"
            )


def _check_signatures(env: Any, params: Any, key: jax.Array) -> None:
    """Return types and shapes of one env's reset and step, abstractly (nothing runs)."""
    reset_out = jax.eval_shape(env.reset, key, params)
    if not (isinstance(reset_out, tuple) and len(reset_out) == 2):
        _fail(f"reset must return (obs, state); got {type(reset_out).__name__} {reset_out}")
    obs, state = reset_out
    action = jax.eval_shape(env.action_space(params).sample, key)
    step_out = jax.eval_shape(env.step, key, state, action, params)
    if not (isinstance(step_out, tuple) and len(step_out) == 6):
        length = len(step_out) if isinstance(step_out, tuple) else type(step_out).__name__
        _fail(
            "step must return (obs, state, reward, terminated, truncated, info) "
            f"(gymnax 1.0); got {length}"
        )
    obs2, state2, reward, terminated, truncated, info = step_out
    _check_same_types("obs", obs2, obs)
    _check_same_types("state", state2, state)
    if reward.shape != () or not jnp.issubdtype(reward.dtype, jnp.floating):
        _fail(f"reward must be a floating () array; got {reward.dtype}{list(reward.shape)}")
    for name, flag in (("terminated", terminated), ("truncated", truncated)):
        if flag.shape != () or flag.dtype != jnp.bool_:
            _fail(f"{name} must be a bool () array; got {flag.dtype}{list(flag.shape)}")
    if not isinstance(info, dict):
        _fail(f"info must be a dict; got {type(info).__name__}")


_STEP_FIELDS = ("obs", "state", "reward", "terminated", "truncated")


def _rollout(
    env: Any,
    reset_key: Callable[[jax.Array], jax.Array],
    params: Any,
    reset_keys: jax.Array,
    action_keys: jax.Array,
    step_keys: jax.Array,
) -> dict[str, dict[str, Any]]:
    """Reset N envs and step them T times (vmapped): ``{"reset": {...}, "steps": {...}}``,
    the steps' leaves (T, N, …)."""
    space = env.observation_space(params)
    obs0, state0 = jax.vmap(env.reset, (0, None))(reset_keys, params)
    first = {"obs": obs0, "state": state0, "in_space": jax.vmap(space.contains)(obs0)}

    def one_step(key, state, action_key):
        action = env.action_space(params).sample(action_key)
        obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)
        done = terminated | truncated
        reset_ok = _tree_equal_traced((obs, state), env.reset(reset_key(key), params))
        final_ok = _tree_equal_traced(info.get("final_observation", obs), obs)  # none: ok
        out = dict(zip(_STEP_FIELDS, (obs, state, reward, terminated, truncated), strict=True))
        out.update(
            in_space=space.contains(obs),
            finite=_all_finite(obs),
            reset_ok=~done | reset_ok,
            final_ok=done | final_ok,
        )
        return state, out

    def body(state, keys):
        k_step, k_action = keys
        return jax.vmap(one_step)(k_step, state, k_action)

    _, steps = jax.lax.scan(body, state0, (step_keys, action_keys))
    return {"reset": first, "steps": steps}


_jit_rollout = jit_in_store("env", "reset_key")(_rollout)


def _first_difference(a: Any, b: Any, rtol: float = 0.0, atol: float = 0.0) -> str | None:
    """Where two pytrees first differ (None: equal; bitwise unless a tolerance is given)."""
    if jax.tree.structure(a) != jax.tree.structure(b):
        return f"tree structure {jax.tree.structure(a)} vs {jax.tree.structure(b)}"
    leaves = jax.tree_util.tree_leaves_with_path(_plain(a))
    for (key_path, x), y in zip(leaves, jax.tree.leaves(_plain(b)), strict=True):
        x, y, path = np.asarray(x), np.asarray(y), jax.tree_util.keystr(key_path)
        if x.shape != y.shape or x.dtype != y.dtype:
            return f"{path}: {x.dtype}{list(x.shape)} vs {y.dtype}{list(y.shape)}"
        if np.issubdtype(x.dtype, np.inexact) and (rtol or atol):
            same = np.allclose(x, y, rtol=rtol, atol=atol, equal_nan=True)
        else:
            same = np.array_equal(x, y, equal_nan=np.issubdtype(x.dtype, np.inexact))
        if not same:
            return f"{path}: values differ"
    return None


def check_env_contract(
    env: Any,
    params: Any = None,
    *,
    key: jax.Array | None = None,
    num_envs: int = 4,
    num_steps: int = 32,
    eager_steps: int = 2,
    reset_key: Callable[[jax.Array], jax.Array] = same_key,
    rtol: float = 0.0,
    atol: float = 0.0,
) -> ContractReport:
    """Check ``env`` (hashable: a static ``jit`` argument) against the gymnax 1.0 contract (module
    docstring) on a random rollout; raises :class:`EnvContractError`. ``reset_key``: the
    ``step_key -> key`` the auto-reset draws from (:func:`same_key` for ``drqn_jax``,
    ``lambda k: jax.random.split(k)[1]`` for gymnax); ``rtol``/``atol``: jit ≡ no-jit tolerance for
    float leaves (default bitwise)."""
    if num_envs < 1 or num_steps < 1 or not 0 <= eager_steps <= num_steps:
        raise ValueError(
            f"need num_envs >= 1, num_steps >= 1 and 0 <= eager_steps <= num_steps; got "
            f"{num_envs}, {num_steps}, {eager_steps}"
        )
    params = env.default_params if params is None else params
    key = jax.random.key(0) if key is None else key
    k_reset, k_action, k_step = jax.random.split(key, 3)
    reset_keys = jax.random.split(k_reset, num_envs)
    action_keys = jax.random.split(k_action, (num_steps, num_envs))
    step_keys = jax.random.split(k_step, (num_steps, num_envs))

    _check_signatures(env, params, reset_keys[0])

    args = (params, reset_keys, action_keys, step_keys)
    rollout = jax.device_get(_jit_rollout(env, reset_key, *args))
    _check_rollout(rollout)

    diff = _first_difference(rollout, jax.device_get(_jit_rollout(env, reset_key, *args)))
    if diff is not None:
        _fail(f"the same keys gave a different rollout: {diff}")

    if eager_steps:  # jit ≡ no jit: the first steps, op by op, equal the compiled ones
        n = eager_steps
        with jax.disable_jit():
            eager = _rollout(env, reset_key, params, reset_keys, action_keys[:n], step_keys[:n])
        first = [{k: r["reset"][k] for k in ("obs", "state")} for r in (eager, rollout)]
        steps = [{k: r["steps"][k] for k in _STEP_FIELDS} for r in (eager, rollout)]
        pairs = [("after reset", first)]
        pairs += [(f"at step {t}", jax.tree.map(lambda x, t=t: x[t], steps)) for t in range(n)]
        for when, pair in pairs:
            diff = _first_difference(*pair, rtol, atol)
            if diff is not None:
                _fail(f"jit differs from no jit {when}: {diff}")

    reward, terminated, truncated = (rollout["steps"][k] for k in _STEP_FIELDS[2:])
    done = terminated | truncated
    return ContractReport(
        num_envs=num_envs,
        num_steps=num_steps,
        terminations=int(terminated.sum()),
        truncations=int(truncated.sum()),
        resets=int(done.sum()),
        reward_min=float(reward.min()),
        reward_max=float(reward.max()),
    )


def _check_rollout(rollout: dict) -> None:
    """The module docstring's rules on a compiled rollout's host copy."""
    first, steps = rollout["reset"], rollout["steps"]
    if not np.all(first["in_space"]):
        outside = np.flatnonzero(~first["in_space"])
        _fail(f"reset: the observation of env(s) {outside} is outside the space")
    rules = (
        (steps["in_space"], "observation outside observation_space(params)"),
        (steps["finite"], "observation not finite"),
        (np.isfinite(steps["reward"]), "reward not finite"),
        (
            steps["reset_ok"],
            "the episode ended but the returned (obs, state) are not reset(reset_key(key), "
            "params)'s",
        ),
        (
            steps["final_ok"],
            "the episode goes on but info['final_observation'] is not the returned observation",
        ),
    )
    for ok, broken in rules:
        if not np.all(ok):
            t, n = np.argwhere(~ok)[0]
            _fail(f"step: {broken} at step {t} of env {n} ({int((~ok).sum())} of {ok.size} steps)")
