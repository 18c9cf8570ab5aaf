"""Errors of the recorder package: one base class, translated at the package edge."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path


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


class ActionStoppedError(RigError):
    """A stop ended an action early: a protective or emergency stop, a lost or silent source.

    The rig raises it from ``perform`` after yielding everything that arrived; the recorder
    keeps that in a file marked incomplete (``<trial>.incomplete.mcap``) and raises it again
    with ``path`` set, so the command says in one line what stopped and where the data are.

    Attributes:
        reason: What stopped the action, one line.
        at_ns: Receive time of the stop on the recorder's clock, ns (0: unknown).
        path: The incomplete recording (None until the recorder wrote it).
    """

    def __init__(self, reason: str, at_ns: int = 0, path: Path | None = None) -> None:
        """Describe the stop."""
        where = f"; what arrived is kept in {path} (marked incomplete)" if path else ""
        super().__init__(f"action stopped: {reason}{where}; record the action again")
        self.reason = reason
        self.at_ns = at_ns
        self.path = path
