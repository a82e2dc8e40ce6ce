"""Readers and writers, one format family per module."""

from .atomic import atomic_path, write_text_atomic
from .surface import SURFACE_FORMATS, read_surface, write_surface

__all__ = ["atomic_path", "write_text_atomic", "read_surface", "write_surface", "SURFACE_FORMATS"]
