"""Errors of results directories: each message is one line for the user (the CLI exits 2)."""

from __future__ import annotations

from compare.exceptions import CompareError


class ResultsError(CompareError):
    """A results directory cannot be used as asked."""


class ResultsConflict(ResultsError):
    """The directory holds results the new ones would replace or mix with (``--overwrite`` replaces)."""


class DirectoryBusy(ResultsError):
    """Another process is writing the directory."""


class OutputUnusable(ResultsError):
    """The output directory cannot take the results (not writable, not enough space)."""
