"""Running experiments: runs, sweeps, the frontier yardstick, studies and their reports."""
