"""Shared fixtures. drqn_jax is imported first so its XLA flags take effect."""

import pytest

import drqn_jax


@pytest.fixture(scope="session")
def env_params():
    """``drqn_jax.make("UrbanPedestrians-v0")``: one env and its default params."""
    return drqn_jax.make("UrbanPedestrians-v0")
