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
SHARED_WHY = ("the real maps and laser logs in ../shared (the folder beside this repository that "
              "holds the shared design documents, maps/ and datasets/); CI requires them "
              "(.ci/run sets CURIO_REQUIRE_SHARED=1)")


def shared_path(*parts: str) -> Path:
    """A file or folder of ../shared; the test is skipped with the reason when it is absent
    (failed instead when CURIO_REQUIRE_SHARED is set, as in CI)."""
    path = SHARED.joinpath(*parts)
    if not path.exists():
        msg = f"{path} is missing: this test needs {SHARED_WHY}"
        if os.environ.get("CURIO_REQUIRE_SHARED"):
            pytest.fail(msg, pytrace=False)
        pytest.skip(msg)
    return path

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
    return shared_path("maps")


@pytest.fixture
def mit_csail_log() -> Path:
    """The MIT CSAIL laser log (CARMEN format) in ../shared/datasets."""
    return shared_path("datasets", "mit-csail.clf")
