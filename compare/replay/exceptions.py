"""Errors of replays: each message is one line for the user (the CLI exits 2)."""

from __future__ import annotations

from compare.exceptions import CompareError


class ReplayError(CompareError):
    """A run cannot be replayed as asked (no such run, method or seed, old results, no encoder)."""
