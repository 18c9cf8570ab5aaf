"""Errors of the recorder package: one base class, translated at the package edge."""

from __future__ import annotations


class RecorderError(Exception):
    """Base class of every error the recorder raises on purpose.

    Messages name the offending value or file and say how to fix the problem.
    """


class CatalogError(RecorderError):
    """An object or action catalog is malformed or names something unknown."""


class OutputExistsError(RecorderError):
    """The recorder refused to overwrite an existing recording."""


class RigError(RecorderError):
    """A rig failed to connect, perform or disconnect."""


class BagImportError(RecorderError):
    """A bag or its topic map cannot be imported: unknown topic, type mismatch, bad window."""
