"""The allocator setting (curio/core/memory.py): found by the 24-hour soak of 2026-12-01, where
each kidnap's global localisation search left the rover 2.8–4.6 MB bigger for good (large
temporary arrays served from the heap once glibc had raised its mmap threshold)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

SEARCHES = textwrap.dedent("""
    import json, sys
    import numpy as np
    from curio.core.config import LocalizationConfig
    from curio.core.geometry import Pose2D
    from curio.core.memory import tune_allocator
    from curio.estimation.localization import Localizer
    from curio.estimation.maps import load_map
    from tests.unit.test_localization_helpers import cast_scan

    if sys.argv[1] == "fixed":
        assert tune_allocator()

    def rss_mb():
        for line in open("/proc/self/status"):
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1024

    laser = Pose2D(0.152, 0.078, 0.0)
    grid = load_map(sys.argv[2])
    loc = Localizer(grid, LocalizationConfig(), laser, seed=1)
    rng = np.random.default_rng(1)
    spots = [Pose2D(2.0, -2.5, 0.3), Pose2D(12.5, 1.5, 1.0), Pose2D(1.0, 11.8, -2.0),
             Pose2D(19.5, 12.0, 2.5), Pose2D(6.0, 0.0, 0.0)]
    rss, kept = [], []
    for k in range(8):  # eight kidnaps: a global search each, to its end
        loc.global_localization()
        for i in range(100):
            loc.update(cast_scan(grid, spots[k % 5], laser, sigma_m=0.02, rng=rng),
                       Pose2D(0.0, 0.0, 0.001 * i))
            if loc.search is None and i > 2:
                break
        kept.extend(bytes(4000) for _ in range(25))  # what a rover keeps meanwhile (logs...)
        rss.append(rss_mb())
    print(json.dumps(rss))
""")


def _rss_after_searches(mode: str) -> list[float]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env["PYTHONPATH"] = str(REPO)
    out = subprocess.run([sys.executable, "-c", SEARCHES, mode,
                          str(REPO / "maps" / "curio_building.yaml")],
                         env=env, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return list(json.loads(out.stdout.strip().splitlines()[-1]))


def test_repeated_global_searches_leave_the_resident_size_flat() -> None:
    rss = _rss_after_searches("fixed")
    # Measured after each search: what one search leaves behind shows from the second on.
    # 0.1 MB a search is kept on purpose; by default glibc kept 4.5–6 MB in 5 of 6 runs
    # (183.9, 188.3, 189.8, ... MB), with the settings 0.55–0.62 MB in all six.
    assert max(rss) - rss[0] < 1.5, rss
