"""Errors raised by the robot models; :class:`RobotError` is the root."""

from __future__ import annotations

from collections.abc import Iterable


class RobotError(Exception):
    """Root of every error raised by :mod:`robots`."""


class UnknownRobot(RobotError):
    """The robot name is not in the registry."""

    def __init__(self, name: str, available: Iterable[str]) -> None:
        names = ", ".join(sorted(available))
        super().__init__(f"unknown robot '{name}'; available: {names}")
        self.name = name


class InvalidSpec(RobotError):
    """A :class:`~robots.spec.RobotSpec` field has an impossible value."""


class InvalidDescription(RobotError):
    """A robot's description file cannot be used (unreadable, unsupported joint, missing limits...).

    The message is one line: the robot, the file and the reason.
    """


class NotInstalled(RobotError):
    """A registered robot's files are not on this machine (e.g. a package it needs is missing)."""


class UnknownFrame(RobotError):
    """The frame name does not exist in the model."""

    def __init__(self, name: str, available: Iterable[str]) -> None:
        names = ", ".join(available)
        super().__init__(f"unknown frame '{name}'; available: {names}")
        self.name = name


class InvalidConfiguration(RobotError):
    """A joint configuration has the wrong shape or non-finite entries."""


class StaleKinematics(RobotError):
    """A :class:`~robots.kinematics.Kinematics` snapshot was read after a newer one was computed."""
