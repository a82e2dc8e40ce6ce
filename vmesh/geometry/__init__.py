"""Geometry kernels: pure, vectorised functions on numpy arrays."""
