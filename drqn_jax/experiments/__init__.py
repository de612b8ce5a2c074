"""Running experiments: one run in a directory (:mod:`~drqn_jax.experiments.runner`,
:mod:`~drqn_jax.experiments.host_loop`, :mod:`~drqn_jax.experiments.checkpoint`),
sweeps (:mod:`~drqn_jax.experiments.sweep`, :mod:`~drqn_jax.experiments.sweep_runner`,
:mod:`~drqn_jax.experiments.memory`), the yardstick
(:mod:`~drqn_jax.experiments.frontier`, :mod:`~drqn_jax.experiments.stats`), the study
and its report (:mod:`~drqn_jax.experiments.study`, :mod:`~drqn_jax.experiments.rows`,
:mod:`~drqn_jax.experiments.report`, :mod:`~drqn_jax.experiments.figures`, the runs store
:mod:`~drqn_jax.experiments.portable`) and the benchmarks' front door
(:mod:`~drqn_jax.experiments.bench`, :mod:`~drqn_jax.experiments.machine`).
"""
