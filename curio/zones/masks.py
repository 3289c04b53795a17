"""Zones as grids: the costmap's keep-out layer, and Nav2 costmap-filter masks to export.

* :func:`keepout_mask` — cells of a grid (resolution, origin, shape of the costmap) that any
  keep-out zone grown by ``margin_m`` touches: they become lethal in the costmap, so the
  planner never plans through a zone and the controller's footprint check never drives into
  one (the inflation keeps the rover's centre the inscribed radius away, as from a wall).
* :func:`export_nav2_masks` — Nav2's convention for costmap filters (``nav2_map_server``'s
  filter masks with a ``costmap_filter_info_server`` each): ``<map>_keepout.yaml/.pgm``
  (type 0, keep-out: occupancy 100 inside a zone, 0 elsewhere, ``mode: trinary``) and
  ``<map>_speed.yaml/.pgm`` (type 2, speed limit in m/s = ``base + multiplier · value`` with
  base 0 and multiplier 0.01: the value is the limit in cm/s, 1..100; 0 = no limit;
  ``mode: raw``), and ``<map>_filters.yaml`` with the two filter-info servers' parameters.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from curio.core.fileio import atomic_write_text
from curio.core.geometry import Pose2D
from curio.estimation.maps import OccupancyGrid, save_map

from .geometry import points_in_polygon
from .model import Zone

__all__ = ["SPEED_MULTIPLIER", "export_nav2_masks", "keepout_mask", "speed_mask", "zone_cells"]

SPEED_MULTIPLIER = 0.01  # m/s per mask value (type 2: absolute speed limit)

BoolArray = npt.NDArray[np.bool_]


def zone_cells(zone: Zone, resolution_m: float, origin: Pose2D, shape: tuple[int, int],
               grow_m: float = 0.0) -> BoolArray:
    """Cells ``(rows, cols)`` whose square touches the zone's polygon grown by ``grow_m``."""
    h, w = shape
    out = np.zeros(shape, dtype=bool)
    poly = origin.inverse().transform_points(zone.vertices()) / resolution_m  # grid cells
    reach = grow_m / resolution_m + 0.7072  # a cell's half diagonal, in cells
    c0 = max(0, int(np.floor(poly[:, 0].min() - reach)))
    c1 = min(w, int(np.ceil(poly[:, 0].max() + reach)) + 1)
    r0 = max(0, int(np.floor(poly[:, 1].min() - reach)))
    r1 = min(h, int(np.ceil(poly[:, 1].max() + reach)) + 1)
    if c0 >= c1 or r0 >= r1:
        return out
    cc, rr = np.meshgrid(np.arange(c0, c1) + 0.5, np.arange(r0, r1) + 0.5)
    centres = np.stack([cc.ravel(), rr.ravel()], axis=1)
    inside = points_in_polygon(centres, poly)
    a, b = poly, np.roll(poly, -1, axis=0)
    d = b - a
    ll = np.maximum((d * d).sum(axis=1), 1e-18)
    near = np.zeros(len(centres), dtype=bool)
    for k in range(0, len(centres), 4096):  # bounded memory on big zones
        p = centres[k:k + 4096]
        rel = p[:, None, :] - a[None, :, :]
        t = np.clip((rel * d[None]).sum(axis=2) / ll[None], 0.0, 1.0)
        q = a[None] + t[..., None] * d[None]
        dist = np.hypot(p[:, None, 0] - q[..., 0], p[:, None, 1] - q[..., 1]).min(axis=1)
        near[k:k + 4096] = dist <= reach
    out[r0:r1, c0:c1] = (inside | near).reshape(r1 - r0, c1 - c0)
    return out


def keepout_mask(zones: list[Zone], resolution_m: float, origin: Pose2D,
                 shape: tuple[int, int], margin_m: float) -> BoolArray:
    """Cells touched by any keep-out zone grown by ``margin_m`` (the costmap's layer)."""
    mask = np.zeros(shape, dtype=bool)
    for zone in zones:
        if zone.kind == "keepout":
            mask |= zone_cells(zone, resolution_m, origin, shape, margin_m)
    return mask


def speed_mask(zones: list[Zone], resolution_m: float, origin: Pose2D,
               shape: tuple[int, int]) -> npt.NDArray[np.float64]:
    """Per cell, the lowest speed limit of the speed zones touching it, m/s (inf: none)."""
    out = np.full(shape, np.inf)
    for zone in zones:
        if zone.kind == "speed" and zone.speed_limit_mps is not None:
            cells = zone_cells(zone, resolution_m, origin, shape)
            out[cells] = np.minimum(out[cells], zone.speed_limit_mps)
    return out


def export_nav2_masks(zones: list[Zone], grid: OccupancyGrid, out_dir: Path,
                      stem: str) -> list[Path]:
    """Write the keep-out and speed masks of ``zones`` on ``grid``'s geometry into
    ``out_dir`` as ``<stem>_keepout``, ``<stem>_speed`` (map_server YAML + PGM) and
    ``<stem>_filters.yaml``; return the files written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    shape = (grid.height, grid.width)
    keep = keepout_mask(zones, grid.resolution_m, grid.origin, shape, 0.0)
    data = np.where(keep, 100, 0).astype(np.int8)
    keep_yaml = save_map(OccupancyGrid(data, grid.resolution_m, grid.origin,
                                       name=f"{stem}_keepout"),
                         out_dir / f"{stem}_keepout.yaml", mode="trinary")
    limits = speed_mask(zones, grid.resolution_m, grid.origin, shape)
    values = np.where(np.isfinite(limits),
                      np.clip(np.round(limits / SPEED_MULTIPLIER), 1, 100), 0).astype(np.int8)
    speed_yaml = save_map(OccupancyGrid(values, grid.resolution_m, grid.origin,
                                        name=f"{stem}_speed"),
                          out_dir / f"{stem}_speed.yaml", mode="raw")
    info = out_dir / f"{stem}_filters.yaml"
    atomic_write_text(info, _filter_info(stem))
    return [keep_yaml, keep_yaml.with_suffix(".pgm"), speed_yaml, speed_yaml.with_suffix(".pgm"),
            info]


def _filter_info(stem: str) -> str:
    """Parameters of Nav2's two costmap_filter_info_server nodes for the masks."""
    return (
        f"# Nav2 costmap filters for the zones of {stem} (written by Curio).\n"
        "# Serve each mask with nav2_map_server (topic_name = mask_topic) and one\n"
        "# costmap_filter_info_server per filter with these parameters.\n"
        "keepout_filter_info_server:\n"
        "  ros__parameters:\n"
        "    type: 0\n"
        "    filter_info_topic: \"/keepout_filter_info\"\n"
        "    mask_topic: \"/keepout_filter_mask\"\n"
        "    base: 0.0\n"
        "    multiplier: 1.0\n"
        f"    # mask: {stem}_keepout.yaml\n"
        "speed_filter_info_server:\n"
        "  ros__parameters:\n"
        "    type: 2\n"
        "    filter_info_topic: \"/speed_filter_info\"\n"
        "    mask_topic: \"/speed_filter_mask\"\n"
        "    base: 0.0\n"
        f"    multiplier: {SPEED_MULTIPLIER}\n"
        f"    # mask: {stem}_speed.yaml (value = limit in cm/s; 0 = no limit)\n"
    )
