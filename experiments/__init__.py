"""Experiments: specs, sweep runner, tables, figures, reports, benchmarks (the CLIs)."""
