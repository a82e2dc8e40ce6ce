"""TOML reading for every Python vmesh supports: ``tomllib`` (3.11+) or its backport ``tomli``."""

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

__all__ = ["tomllib"]
