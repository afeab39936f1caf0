"""The error of recordings and their log readers (:mod:`sim.recording`,
:mod:`sim.csv_logs`, :mod:`sim.ros_bags`), in a module of its own so the readers need not
import the recording module that imports them."""

from __future__ import annotations

__all__ = ["RecordingError"]


class RecordingError(ValueError):
    """A recording (its logs or its TOML file) is invalid; the message names file and field."""
