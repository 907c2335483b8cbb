"""Simulation toolkit: test shapes, free-state generators, virtual scanner, defect injection.

Every generator is deterministic from its ``seed``. Used by tests and benchmarks to measure
accuracy against exact ground truth (paper Sections 4.2, 4.3, 7.1, 8.3).
"""
