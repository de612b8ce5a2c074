"""Minimal gymnax-style spaces: ``Discrete``, ``Box``, ``Dict`` with ``sample`` and ``contains``."""

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True)
class Discrete:
    """Integers ``start, …, start + n - 1``."""

    n: int
    start: int = 0
    dtype: Any = jnp.int32

    @property
    def shape(self) -> tuple[int, ...]:
        return ()

    def sample(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, (), self.start, self.start + self.n, dtype=self.dtype)

    def contains(self, x: Any) -> jax.Array:
        x = jnp.asarray(x)
        return jnp.logical_and(x >= self.start, x < self.start + self.n)


@dataclasses.dataclass(frozen=True, eq=False)
class Box:
    """Reals in ``[low, high]`` (bounds broadcast to ``shape``)."""

    low: Any
    high: Any
    shape: tuple[int, ...]
    dtype: Any = jnp.float32

    def sample(self, key: jax.Array) -> jax.Array:
        low = np.broadcast_to(np.asarray(self.low, np.float32), self.shape)
        high = np.broadcast_to(np.asarray(self.high, np.float32), self.shape)
        finite_high = np.where(np.isfinite(high), high, low + 1.0)
        return jax.random.uniform(key, self.shape, self.dtype, low, finite_high)

    def contains(self, x: Any) -> jax.Array:
        x = jnp.asarray(x)
        ok = jnp.all((x >= self.low) & (x <= self.high))
        return jnp.logical_and(ok, x.shape == self.shape)


@dataclasses.dataclass(frozen=True, eq=False)
class Dict:
    """A mapping of named sub-spaces."""

    spaces: dict[str, Any]

    def sample(self, key: jax.Array) -> dict[str, jax.Array]:
        keys = jax.random.split(key, len(self.spaces))
        return {name: s.sample(k) for (name, s), k in zip(self.spaces.items(), keys, strict=True)}

    def contains(self, x: Any) -> jax.Array:
        get = (lambda n: x[n]) if isinstance(x, dict) else (lambda n: getattr(x, n))
        ok = jnp.asarray(True)
        for name, space in self.spaces.items():
            ok = jnp.logical_and(ok, space.contains(get(name)))
        return ok
