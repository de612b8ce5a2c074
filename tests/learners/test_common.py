"""What the learners share (drqn_jax/learners/common.py and the other shared modules
of drqn_jax/learners/): they import no learner, and no learner imports another."""

from __future__ import annotations

from tests.test_structure import import_graph

#: The learners: a subpackage or module each.
LEARNERS = ("drqn_jax.learners.dqn", "drqn_jax.learners.ppo", "drqn_jax.learners.pqn")


def learner_of(module: str) -> str | None:
    """The learner ``module`` belongs to, or None for shared code."""
    return next((n for n in LEARNERS if module == n or module.startswith(f"{n}.")), None)


def crossings(graph: dict[str, set[str]]) -> list[str]:
    """``a -> b`` for each module of drqn_jax/learners/ (its ``__init__``, which picks
    the learner, left out) that imports a learner other than its own."""
    return sorted(
        f"{module} -> {other}"
        for module, imported in graph.items()
        if module.startswith("drqn_jax.learners.")
        for other in imported
        if learner_of(other) not in (None, learner_of(module))
    )


def test_the_crossing_finder_finds_a_crossing():
    graph = {
        "drqn_jax.learners.common": {"drqn_jax.learners.dqn.replay"},
        "drqn_jax.learners.pqn": {"drqn_jax.learners.common", "drqn_jax.learners.ppo"},
        "drqn_jax.learners.dqn.train": {"drqn_jax.learners.dqn.replay"},
        "drqn_jax.learners": {"drqn_jax.learners.ppo"},
    }
    assert crossings(graph) == [
        "drqn_jax.learners.common -> drqn_jax.learners.dqn.replay",
        "drqn_jax.learners.pqn -> drqn_jax.learners.ppo",
    ]


def test_shared_code_imports_no_learner_and_learners_not_each_other():
    assert crossings(import_graph()) == []


def test_the_discount_and_lambdas_are_per_decision():
    """A decision of k ticks discounts by γ_tick^k (and λ^k for PQN and PPO), so
    ``train.gamma`` keeps its horizon in seconds; k = 1 leaves the hyperparameters be."""
    import numpy as np

    from drqn_jax.learners.common import per_decision
    from drqn_jax.learners.hyperparams import Hyperparams
    from drqn_jax.learners.task import make_task

    hp = Hyperparams(gamma=0.99, gae_lambda=0.95, q_lambda=0.65)
    assert per_decision(hp, make_task("UrbanPedestrians-v0")) is hp
    task = make_task("UrbanPedestrians-v0", (("decision_steps", 5),))
    assert task.decision_steps == 5
    per = per_decision(hp, task)
    np.testing.assert_allclose(
        [per.gamma, per.gae_lambda, per.q_lambda], [0.99**5, 0.95**5, 0.65**5], rtol=1e-6
    )
    assert per.learning_rate == hp.learning_rate
