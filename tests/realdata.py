"""Where the real frames are, and what a test that needs them does when they are not there.

``../shared/realdata`` lies beside the repository where CI and the developers clone it; a user's
fresh clone has no such folder. A test that needs it takes the ``realdata_dir`` fixture (or calls
:func:`need_realdata`): on a fresh clone it is skipped with one stated reason; with ``CI`` set, or
``DROPVISION_REQUIRE_REALDATA=1``, a missing folder is a failure naming it.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REALDATA = Path(__file__).resolve().parents[2] / "shared" / "realdata"
REQUIRE_ENV = "DROPVISION_REQUIRE_REALDATA"
MISSING = f"{REALDATA} is not there (the real frames, ../shared/realdata beside the clone)"


def realdata_required() -> bool:
    """Whether a missing folder fails (CI, or :data:`REQUIRE_ENV` = 1) instead of skipping."""
    return bool(os.environ.get("CI")) or os.environ.get(REQUIRE_ENV) == "1"


def need_realdata() -> Path:
    """:data:`REALDATA`, or skip the calling test (a fresh clone), or fail it (CI)."""
    if REALDATA.is_dir():
        return REALDATA
    if realdata_required():
        pytest.fail(f"{MISSING}; with CI or {REQUIRE_ENV}=1 set it is required")
    pytest.skip(MISSING)
