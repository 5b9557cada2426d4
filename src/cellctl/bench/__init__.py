"""Benchmark scripts: each prints medians and ratios to a simple baseline (``python -m cellctl.bench.NAME``)."""
