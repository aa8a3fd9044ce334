"""Comparison harness: simulation, sensing, scenarios, metrics, CLI."""
