"""Shared fixtures. Real data lives outside the project, at ../shared/data or $HIPPO_NAV_DATA."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path | None:
    env = os.environ.get("HIPPO_NAV_DATA")
    path = Path(env) if env else PROJECT_ROOT.parent / "shared" / "data"
    return path if path.is_dir() else None


@pytest.fixture(scope="session")
def shared_data() -> Path:
    path = shared_data_dir()
    if path is None:
        pytest.skip("real data not found: set HIPPO_NAV_DATA or place it at ../shared/data")
    return path
