"""Skeleton kernels split by stage (issue 20); :mod:`vmesh.geometry.skeleton_ops` and
:mod:`vmesh.geometry.skeleton_extract` hold the rest for now."""
