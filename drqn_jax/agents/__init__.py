"""Policies behind one interface: rule-based (paper §V-E), random, constant, trained DRQN,
and the privileged planner (SPEC §9: a ceiling, not a learner)."""

from drqn_jax.agents.base import Agent, constant_agent, drqn_agent, random_agent
from drqn_jax.agents.planner import planner_agent
from drqn_jax.agents.rule_based import RuleBasedParams, rule_based_agent

__all__ = [
    "Agent",
    "RuleBasedParams",
    "constant_agent",
    "drqn_agent",
    "planner_agent",
    "random_agent",
    "rule_based_agent",
]
