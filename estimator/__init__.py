"""Estimators: everything that turns sensor observations into pose estimates.

This package imports neither :mod:`sim` nor :mod:`experiments`, so it can be used on real
logs without the simulator installed.
"""
