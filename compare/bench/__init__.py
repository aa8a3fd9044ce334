"""Micro-benchmarks: solvers on the paper's case-2 hierarchy, and the sensing pipeline."""
