"""Skeleton kernels split by stage (issue 20): the extraction from a signed distance
(:mod:`.extract` and its stages :mod:`.voxelize`, :mod:`.thin`, :mod:`.trace`,
:mod:`.branch_graph`, :mod:`.ends`, :mod:`.end_faces`, :mod:`.resample` over the probes of
:mod:`.probe`), centerline defects and marching; :mod:`vmesh.geometry.skeleton_ops` holds
the rest for now."""
