"""Other libraries' views of the simulator: Gymnasium envs and rerun recordings."""
