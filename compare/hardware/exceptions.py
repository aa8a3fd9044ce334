"""Errors of the hardware bridge; the CLI prints one line and exits 2 for each of them."""

from __future__ import annotations

from compare.exceptions import CompareError


class HardwareError(CompareError, RuntimeError):
    """Root of the hardware bridge's errors (under :class:`compare.exceptions.CompareError`)."""


class RosUnavailable(HardwareError):
    """ROS 1 (rospy, the message packages) cannot be imported; the message says how to install it."""


class MasterUnreachable(HardwareError):
    """No ROS master answers at ``ROS_MASTER_URI``."""


class StartRefused(HardwareError):
    """A start-up check failed (arm outside its safety thresholds, camera transform missing, no data)."""
