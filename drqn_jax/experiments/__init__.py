"""Running experiments: single runs, sweeps, the frontier yardstick, studies and their
reports, and the benchmarks' front door."""
