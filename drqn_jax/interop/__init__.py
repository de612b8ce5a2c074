"""Other libraries' views of the simulator: Gymnasium's single and vector envs
(:mod:`~drqn_jax.interop.gymnasium_env`) and rerun recordings of episodes and
training curves (:mod:`~drqn_jax.interop.recording`).
"""
