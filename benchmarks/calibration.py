"""A speed calibration of the host, measured in the same run as a benchmark's figures.

CPU figures move with the machine (a Raspberry Pi 4 core is 3–5× slower than the development
machines, and those differ by 1.8× among themselves). The calibration is the throughput of the
naive per-beam Python ray caster (``curio.sim.raycast.naive_cast``, the peer of ``curio bench
sim``): 360 beams from the default world's start pose, in scans per CPU second of this process.
It is pure interpreted Python, like most of the application's per-message work, and needs no
compiled kernel. A figure divided by the calibration (``x_per_calib``) compares across hosts:
``app_cpu_per_sim_s × naive_scans_per_cpu_s`` is the application's cost in naive scans per
simulated second, whatever the machine.
"""

from __future__ import annotations

import math

import numpy as np

from curio.core.clock import process_cpu_time
from curio.core.config import REPO_ROOT, load_config
from curio.sim.raycast import naive_cast
from curio.sim.world import World

__all__ = ["naive_scans_per_cpu_s"]


def naive_scans_per_cpu_s(min_cpu_s: float = 1.0) -> float:
    """Naive 360-beam scans per CPU second (at least ``min_cpu_s`` of CPU, whole scans)."""
    cfg = load_config(REPO_ROOT / "config.toml", ["web.enabled=false"])
    world = World.from_config(cfg)
    pose = world.truth_pose
    angles = -math.pi + np.arange(360, dtype=np.float64) * (2.0 * math.pi / 360)
    naive_cast(world.grid, pose.x, pose.y, angles[:4], cfg.sim.lidar_range_max_m)  # warm
    scans = 0
    c0 = process_cpu_time()
    while True:
        naive_cast(world.grid, pose.x, pose.y, angles, cfg.sim.lidar_range_max_m)
        scans += 1
        used = process_cpu_time() - c0
        if used >= min_cpu_s:
            return scans / used
