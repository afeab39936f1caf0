"""Simulation: MuJoCo platforms following paths, ground truth, and noise injectors.

Imports :mod:`estimator` (for sensor configurations) but never :mod:`experiments`.
"""
