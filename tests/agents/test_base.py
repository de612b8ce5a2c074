"""The agent interface (drqn_jax/agents/base.py): an ``Agent`` is a pytree whose
parameters are its leaves and whose functions and name are static."""

from __future__ import annotations

import jax

import drqn_jax


def test_agent_is_a_pytree_with_static_functions():
    agent = drqn_jax.rule_based_agent()
    leaves, treedef = jax.tree.flatten(agent)
    assert len(leaves) == 5  # the four thresholds and the anticipation horizon
    rebuilt = jax.tree.unflatten(treedef, leaves)
    assert rebuilt.act_fn is agent.act_fn and rebuilt.name == "rule-based"
