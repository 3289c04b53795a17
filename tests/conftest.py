"""Shared fixtures: configs on temporary data directories, buses, simulated clocks."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from curio.core.bus import Bus
from curio.core.clock import SimClock
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.topics import make_bus

SHARED = REPO_ROOT.parent / "shared"

# CI explores the same hypothesis examples every run (reproducible); locally they vary.
settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


@pytest.fixture
def cfg(tmp_path: Path) -> Config:
    """The shipped config, with data written to a temporary directory and the web off."""
    return load_config(REPO_ROOT / "config.toml",
                       [f'data_dir="{tmp_path / "data"}"', "web.enabled=false"])


@pytest.fixture
def bus() -> Bus:
    """A bus with every topic declared."""
    return make_bus()


@pytest.fixture
def sim_clock() -> SimClock:
    """A simulated clock running as fast as possible."""
    return SimClock()


@pytest.fixture
def shared_maps() -> Path:
    """The real maps in ../shared/maps (made outside this project)."""
    return SHARED / "maps"
