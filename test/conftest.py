"""Shared pytest fixtures: repo_root, shared_dir (MMM_SHARED, default <repo>/../shared)."""
import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """Absolute path of the repository root."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """The shared data dir: $MMM_SHARED, else <repo>/../shared; skips the test if absent."""
    path = Path(os.environ.get("MMM_SHARED") or REPO_ROOT.parent / "shared")
    if not path.is_dir():
        pytest.skip(f"shared data dir {path} not found (set MMM_SHARED)")
    return path
