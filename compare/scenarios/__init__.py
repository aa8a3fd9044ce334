"""Scenarios drawn from a seed: the randomized families' start pose, waypoints, person and sensor noise."""
