"""The replay DQN family (paper §V-B; SPEC §7): the paper's DRQN and its DQN and
frame-stacked DQN ablations, trained by Double DQN on a whole-episode replay.

:mod:`~drqn_jax.learners.dqn.acting` (ε-greedy acting, with its teacher),
:mod:`~drqn_jax.learners.dqn.replay` (the episode replay and its windows),
:mod:`~drqn_jax.learners.dqn.loss` (the sequence loss),
:mod:`~drqn_jax.learners.dqn.update` (one gradient update) and
:mod:`~drqn_jax.learners.dqn.train` (``make_dqn``: the whole run as one program).
"""
