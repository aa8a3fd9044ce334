"""Scenario families: the paper's scripted case studies and randomized scenarios."""

from __future__ import annotations

from compare.scenarios.random_scenario import realize

__all__ = ["realize"]
