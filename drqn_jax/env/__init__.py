"""The simulator (SPEC §1–5): a pure module per concern, wired by :mod:`~drqn_jax.env.urban`."""
