"""Errors of the sensing package (one root: :class:`SensingError`)."""

from __future__ import annotations

from compare.exceptions import CompareError


class SensingError(CompareError):
    """Root of the sensing errors: bad scene, camera or sensing parameters (under :class:`CompareError`)."""


class UnknownSceneElement(SensingError):
    """A camera, body or geom named in the arguments is not in the MuJoCo model."""

    def __init__(self, kind: str, name: str, available: list[str]) -> None:
        super().__init__(f"unknown {kind} '{name}'; available: {', '.join(available) or '(none)'}")
        self.kind = kind
        self.name = name
