"""Tests of drqn_jax/agents/: test_<module>.py per module."""
