"""Shared fixtures: the real data beside the checkout, a quiet Rerun, temporary output folders."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# Rerun must never phone home from tests.
os.environ.setdefault("RERUN_ANALYTICS", "0")

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("ACCELLOG_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data (real recordings). CI has it beside the checkout; skip elsewhere."""
    if not (SHARED_DATA / "capstone").is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(autouse=True, scope="session")
def _rerun_config_home(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Keep Rerun's config (analytics) in a throw-away folder with analytics disabled."""
    cfg = tmp_path_factory.mktemp("xdg_config")
    (cfg / "rerun").mkdir()
    (cfg / "rerun" / "analytics.json").write_text('{"analytics_enabled": false}')
    os.environ["XDG_CONFIG_HOME"] = str(cfg)
