"""The benchmark suite: python -m benchmarks.NAME or drqn-jax bench NAME."""
