"""Errors of the replay package: one base class, translated at the package edge."""

from __future__ import annotations


class ReplayError(Exception):
    """Base class of every error the replay package raises on purpose.

    Messages name the offending file or value and say how to fix the problem.
    """


class RecordingError(ReplayError):
    """A recording cannot be read: corrupt, incomplete, or not following the contract."""
