"""Import drqn_jax before any JAX computation so its XLA flags take effect."""

import drqn_jax  # noqa: F401
