"""Hierarchical-QP baseline over the same tpik hierarchy, and the mink peer."""
