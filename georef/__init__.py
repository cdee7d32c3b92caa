"""georef: GPS/INS direct georeferencing of aerial imagery — exterior orientation, with sigmas, for every frame."""

from __future__ import annotations


def __getattr__(name: str) -> str:
    """``georef.__version__``: the installed distribution's version, looked up on first use (no import cost)."""
    if name == "__version__":
        from importlib import metadata

        try:
            return metadata.version("georef")
        except metadata.PackageNotFoundError:
            return "unknown"
    raise AttributeError(f"module 'georef' has no attribute {name!r}")
