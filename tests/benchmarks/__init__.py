"""Tests of benchmarks/: test_<benchmark>.py per benchmark, at --quick sizes."""
