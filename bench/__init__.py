"""Benchmarks: ``make bench`` (= ``python -m bench``) runs every ``bench_*.py`` module's
``main()``; each prints its numbers and asserts nothing (speed is reported, not tested)."""
