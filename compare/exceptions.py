"""The root of every error :mod:`compare` raises: :class:`CompareError`.

Each sub-package keeps its own errors next to the code that raises them, all under this root:

* :class:`compare.config.ConfigError` (and :class:`compare.campaign.executors.ExecutorUnavailable`),
* :class:`compare.methods.UnknownMethod`,
* :class:`compare.analysis.metrics.MetricsError`,
* :class:`compare.analysis.exceptions.ResultsError` (``ResultsConflict``, ``DirectoryBusy``, ``OutputUnusable``),
* :class:`compare.sensing.exceptions.SensingError` (and ``UnknownSceneElement``),
* :class:`compare.hardware.exceptions.HardwareError` (``RosUnavailable``, ``MasterUnreachable``,
  ``StartRefused``).

The errors that callers caught as ``ValueError`` or ``RuntimeError`` before this root existed
still derive from those. The CLI prints any of them (and the roots of the packages below,
:class:`robots.exceptions.RobotError`, :class:`tpik.exceptions.TpikError`,
:class:`qp_baseline.exceptions.HqpError`) as one line and exits with code 2.
"""

from __future__ import annotations


class CompareError(Exception):
    """Root of every error raised by :mod:`compare`."""


__all__ = ["CompareError"]
