"""Tests of drqn_jax/env/: test_<module>.py per module, and cross-cutting env checks."""
