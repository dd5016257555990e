"""Errors of the mission control system's ground segment."""

from __future__ import annotations

__all__ = ["GroundError"]


class GroundError(RuntimeError):
    """The ground segment (Yamcs, its data link, its archive) cannot do what was asked; the message names
    the input or the service and the reason."""
