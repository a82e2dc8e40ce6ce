"""Deterministic synthetic vessel surfaces with ground-truth skeletons.

See :mod:`data_synthetic.generate` for the cases, the file format and the command line.
"""
