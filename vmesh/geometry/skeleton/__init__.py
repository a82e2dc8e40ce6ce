"""Skeleton kernels split by stage (issue 20): the extraction from a signed distance
(:mod:`.extract` and its stages :mod:`.voxelize`, :mod:`.thin`, :mod:`.trace`,
:mod:`.branch_graph`, :mod:`.ends`, :mod:`.end_faces`, :mod:`.resample` over the probes of
:mod:`.probe`), centerline defects and marching, and the kernels on skeletons that
:mod:`vmesh.geometry.skeleton_ops` re-exports: graph structure (:mod:`.graph`), graphs
from polylines (:mod:`.polylines`), signed distance helpers (:mod:`.distance`), cleaning
(:mod:`.clean`), ends to caps and grafting (:mod:`.graft`), resampling (:mod:`.sample`),
branch tree and tags (:mod:`.tags`)."""
