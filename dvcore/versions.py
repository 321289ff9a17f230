"""Software versions written into every result, so that it can be reproduced."""

from __future__ import annotations

import functools
import platform
from importlib import metadata

_PACKAGES = ("dropvision", "numpy", "scipy", "pandas", "pyarrow", "opencv-python-headless",
             "scikit-image", "tifffile", "rerun-sdk", "numba", "isal", "imagecodecs")


def software_versions() -> dict[str, str]:
    """Versions of Python and of the packages a result depends on ("missing" if absent)."""
    return dict(_versions())


@functools.lru_cache(maxsize=1)
def _versions() -> dict[str, str]:
    """Read once per process (some 30 ms: a folder of shots writes them once per shot)."""
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "missing"
    return out
