"""Tracking a known object through a stream of frames (:mod:`masknet.tracking.tracker`),
and synthetic sequences with known truth to measure it (:mod:`masknet.tracking.sequences`)."""

from masknet.tracking.tracker import STATES, Tracker, TrackResult, track

__all__ = ["STATES", "TrackResult", "Tracker", "track"]
