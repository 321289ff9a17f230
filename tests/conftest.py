"""Fixtures shared by the test modules."""

from __future__ import annotations

import pytest

from realdata import need_realdata


@pytest.fixture
def realdata_dir():
    """``../shared/realdata``: skipped on a fresh clone without it, a failure in CI (tests/realdata.py)."""
    return need_realdata()
