"""Errors of the atikt package: one base class for every deliberate failure."""

from __future__ import annotations


class AtiktError(Exception):
    """Base class of every error atikt raises on purpose (bad shapes, bad parameters, ...)."""


class NotFittedError(AtiktError):
    """A model was used before ``fit``."""


class NumericalError(AtiktError):
    """A numerical step failed (e.g. a kernel matrix that is not positive definite)."""
