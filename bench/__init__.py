"""Benchmark harness: paper table specs, runner, cache, LaTeX tables, plots and report."""
