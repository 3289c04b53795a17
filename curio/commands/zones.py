"""``curio zones``: the zones of a map, offline (the dashboard edits them on a running rover).

    curio zones list [--map YAML] [--config PATH] [--set KEY=VALUE]...
    curio zones export [--map YAML] [--out DIR] [--config PATH] [--set KEY=VALUE]...

``list`` prints the zones kept for the map (``<data_dir>/<zones.directory>/<map name>.json``;
the map defaults to the navigation map, ``localization.map_yaml`` or ``sim.world``).
``export`` writes them as Nav2 costmap-filter masks — ``<map>_keepout.yaml/.pgm``,
``<map>_speed.yaml/.pgm`` and ``<map>_filters.yaml`` — beside the map (or into ``--out``).

Exit codes: 0 done; 2 on bad arguments, a missing or unreadable map or zone file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from curio.core.config import load_config
from curio.core.errors import SetupError
from curio.estimation.maps import MapError, load_map
from curio.estimation.wiring import map_path
from curio.zones.masks import export_nav2_masks
from curio.zones.store import ZoneStore
from curio.zones.wiring import zone_file

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="curio zones", description="The keep-out and speed "
                                 "zones of a map: list them, export them as Nav2 masks.")
    sub = ap.add_subparsers(dest="action", required=True)
    for name, helptext in (("list", "print the zones of the map"),
                           ("export", "write the Nav2 filter masks beside the map")):
        p = sub.add_parser(name, help=helptext)
        p.add_argument("--map", dest="map_yaml", help="map YAML (default: the navigation map)")
        p.add_argument("--config", help="config file (default: ./config.toml or the shipped)")
        p.add_argument("--set", dest="overrides", action="append", default=[],
                       metavar="KEY=VALUE", help="config override (repeatable)")
        if name == "export":
            p.add_argument("--out", type=Path, help="directory (default: beside the map)")
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    args = _parser().parse_args(argv)
    try:
        cfg = load_config(args.config, args.overrides)
        yaml_path = Path(args.map_yaml) if args.map_yaml else Path(map_path(cfg))
        name = yaml_path.stem
        store = ZoneStore(zone_file(cfg, name), name, cfg.robot.max_wheel_speed_mps)
        if args.action == "list":
            zones = store.list_zones()
            if not zones:
                print(f"no zones for {name} ({store.path})")
            for z in zones:
                limit = f" {z.speed_limit_mps:g} m/s" if z.speed_limit_mps is not None else ""
                print(f"{z.id:>3}  {z.kind:<7} {z.name}{limit}  {len(z.polygon)} points")
            return 0
        grid = load_map(yaml_path)
        out = args.out or yaml_path.parent
        for path in export_nav2_masks(store.list_zones(), grid, out, name):
            print(path)
        return 0
    except (SetupError, MapError, OSError) as exc:
        print(f"curio zones: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
