"""The urban-pedestrian simulator (SPEC §1–5): one pure module per concern, wired by
:mod:`~drqn_jax.env.urban` (the gymnax contract); docs/architecture.md maps them."""
