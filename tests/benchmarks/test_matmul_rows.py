"""benchmarks/matmul_rows.py: the shipped network's products, and no batch of at least
``MIN_BATCH`` rows rounds them differently (what ``evaluation.map_episodes`` relies on)."""

from benchmarks.matmul_rows import differing_rows, network_products
from drqn_jax.evaluation import MIN_BATCH


def test_the_shipped_networks_products():
    products = network_products()
    assert products["conv_0"] == (8 * 6 * 4, 32)
    assert products["gru1 state"] == (256, 768)
    assert products["q"] == (256, 4)


def test_no_batch_of_min_batch_rows_or_more_rounds_differently():
    rows = [MIN_BATCH, MIN_BATCH + 1, 200, 333]
    for k, n in {network_products()[p] for p in ("gru1 state", "gru2 input", "q")}:
        assert differing_rows(k, n, rows) == [], (k, n)
