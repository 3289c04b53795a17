"""The compiled kernels' cache: found without registration, redirected by numba_cache_dir,
reported cold or warm, preloaded; ``curio check`` says so and ``curio warmup`` fills it."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from curio import kernels
from curio.commands import check
from curio.core.config import REPO_ROOT, Config, load_config
from curio.core.errors import SetupError


@pytest.fixture
def restore_cache_dir() -> Iterator[None]:
    """Put numba's cache back where it was (next to the sources) after the test."""
    before = os.environ.get("NUMBA_CACHE_DIR")
    yield
    if before is None:
        os.environ.pop("NUMBA_CACHE_DIR", None)
    else:
        os.environ["NUMBA_CACHE_DIR"] = before
    from numba.core import config as numba_config

    numba_config.reload_config()  # type: ignore[no-untyped-call]
    for disp in kernels.dispatchers().values():
        disp.enable_caching()


def _cfg(tmp: Path | None) -> Config:
    sets = [] if tmp is None else [f'numba_cache_dir="{tmp}"']
    return load_config(REPO_ROOT / "config.toml", sets)


def test_every_cached_kernel_is_found() -> None:
    found = kernels.dispatchers()
    sources = [p.read_text(encoding="utf-8") for p in kernels.PACKAGE_DIR.rglob("*.py")
               if p.name != "kernels.py"]
    on_disk = sum(text.count(kernels.MARKER) for text in sources)
    inline = sum(text.count('inline="always"') for text in sources)
    assert len(found) == on_disk - inline
    assert "curio.sim.raycast_kernel.cast_beams" in found
    assert "curio.estimation.scan_matching_kernels._score" not in found  # inlined helper


_COLD_START = """
import json, sys
from pathlib import Path
import numpy as np
from curio import kernels
from curio.core.config import REPO_ROOT, load_config
where = kernels.use_cache_dir(load_config(REPO_ROOT / "config.toml",
                                          [f'numba_cache_dir="{sys.argv[1]}"']))
cold = all(k.cached == 0 for k in kernels.status())
from curio.safety.kernel import polygon_distances_into
from curio.safety.stop_zone import polygon_distances
inside = Path(polygon_distances_into._cache.cache_path).is_relative_to(where)
polygon_distances(np.array([[0.5, 0.5]]), np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
cached = {k.name: k.cached for k in kernels.status()}["curio.safety.kernel.polygon_distances_into"]
loaded, still_cold = kernels.preload()
print(json.dumps({"where": str(where), "cold": cold, "inside": inside, "cached": cached,
                  "loaded": loaded,
                  "still_cold": "curio.safety.kernel.polygon_distances_into" in still_cold}))
"""


def test_the_cache_dir_moves_every_kernel_and_starts_cold(tmp_path: Path) -> None:
    """In a fresh interpreter (a kernel another test compiled in this one is already in memory,
    and a kernel in memory is neither loaded from nor saved to the cache)."""
    where = tmp_path / "numba"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", _COLD_START, str(where)], env=env,
                         capture_output=True, text=True, timeout=300, check=True).stdout
    got = json.loads(out.strip().splitlines()[-1])
    assert got["where"] == str(where) and where.is_dir()
    assert got["cold"] and got["inside"]
    assert got["cached"] == 1
    assert list(where.rglob("*.nbi")), "the index went into numba_cache_dir"
    assert got["loaded"] == 1 and not got["still_cold"]


def test_check_warns_about_a_cold_cache(tmp_path: Path, restore_cache_dir: None) -> None:
    row = check.kernel_cache_row(_cfg(tmp_path / "empty"))
    assert row.status == "warn" and "curio warmup" in row.fix
    assert f"{len(kernels.dispatchers())} of {len(kernels.dispatchers())}" in row.detail


def test_messages_name_the_cache_numba_really_uses(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """With no numba_cache_dir, an inherited NUMBA_CACHE_DIR is where the kernels go: the
    messages of ``curio check`` and ``curio warmup`` must say so, not "next to the sources"."""
    assert kernels.describe(tmp_path) == str(tmp_path)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "env"))
    assert kernels.describe(None) == f"NUMBA_CACHE_DIR={tmp_path / 'env'}"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert kernels.describe(None) == "next to the sources"


def test_an_unwritable_cache_dir_is_one_clear_error(tmp_path: Path,
                                                     restore_cache_dir: None) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(SetupError, match="numba_cache_dir"):
        kernels.use_cache_dir(_cfg(blocker / "numba"))


@pytest.mark.slow
@pytest.mark.slow
def test_warmup_compiles_every_kernel_from_a_cold_cache(tmp_path: Path,
                                                         restore_cache_dir: None) -> None:
    """From an empty cache, in a fresh interpreter (as on a new install): the workload must
    reach every kernel in the layouts the application uses, or every start would compile
    again (the people and crowd kernels were once missed)."""
    where = tmp_path / "cold"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(where)}
    done = subprocess.run([sys.executable, "-m", "curio", "warmup"], env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    n = len(kernels.dispatchers())
    assert f"compiled kernels: {n} of {n} in the cache" in done.stdout
    assert check.kernel_cache_row(_cfg(where)).status == "ok"


def test_the_warmup_drives_the_shipped_tour_when_the_rover_has_no_stops(tmp_path: Path) -> None:
    """A rover whose tours are authored on the dashboard configures no ``bt.tour_stops``:
    the warmup's guided tour refused to start (ScenarioFailed), the warmup failed and every
    kernel compiled inside the running rover (the soak's rover, 2026-12-01). Its workload
    now drives the shipped building's tour."""
    from curio.commands.warmup import _workload_config
    from curio.scenarios.base import ScenarioArgs
    from curio.scenarios.guided_tour import GuidedTourScenario

    shipped = _cfg(None)
    rover = load_config(REPO_ROOT / "config.toml",
                        ["bt.tour_stops=[]", 'sim.world="elsewhere.yaml"'])
    run = _workload_config(rover, tmp_path, "localize", 8)
    assert run.bt.tour_stops == shipped.bt.tour_stops and run.bt.tour_stops
    assert Path(run.sim.world) == shipped.resolve(shipped.sim.world)
    GuidedTourScenario().configure(run, ScenarioArgs())  # raised before
    own = _workload_config(shipped, tmp_path, "localize", 8)  # stops of its own: kept
    assert own.sim.world == shipped.sim.world


def test_a_kernel_compiling_while_the_rover_runs_is_logged(
        caplog: pytest.LogCaptureFixture) -> None:
    """After the start's preload, a compilation (a layout the warmup never made) is a warning
    naming the kernel and its types; a call that needs no compilation says nothing."""
    from numba import njit

    @njit  # type: ignore[misc]
    def twice(a: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
        return a * 2.0

    kernels.watch_compiles()
    kernels.watch_compiles()  # idempotent: one warning per compilation, not two
    with caplog.at_level(logging.WARNING, logger="curio.kernels"):
        twice(np.zeros(3))
        twice(np.ones(3))  # the same types: no compilation
        twice(np.zeros((3, 2))[:, 0])  # a strided slice: another layout, compiled
    said = [r.getMessage() for r in caplog.records if "compiled while the rover runs" in
            r.getMessage()]
    assert len(said) == 2 and all("twice" in m for m in said)
    assert "'A'" in said[1]
