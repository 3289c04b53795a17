"""What the dashboard asks of whoever runs the App (``curio run``'s host,
:class:`curio.commands.host.MapHost`), and the App's configuration for one map of the library.

Switching maps rebuilds the App in-process (docs/maps.md says why): the host stops the rover,
stops the App, and builds a new one whose configuration points at the new map — its map YAML,
its simulated building, its paths, tours and schedules (:func:`config_for`). The dashboard's
handlers only *ask* (:class:`MapControl`); the host answers at once (refusals as
:class:`~curio.maps.library.MapLibraryError`) and does the work after the answer has gone out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

from curio.core.config import Config
from curio.maps.library import MapLibrary

__all__ = ["MAPPING_SCRATCH", "MapControl", "MapsAccess", "config_for"]

# Where a mapping run's map is saved when its App stops (in the library's directory).
MAPPING_SCRATCH = ".mapping/mapping.yaml"


class MapControl(Protocol):
    """The host's side: each call checks and answers at once, the work follows."""

    def state(self) -> dict[str, Any]:
        """``{active, mapping, switching, pose_needed, message}`` for the page."""

    def switch(self, name: str, actor: str) -> str:
        """Make ``name`` the active map; return a sentence (refused while a tour runs)."""

    def reload(self, actor: str, why: str) -> str:
        """Rebuild the App on the same map (a saved edit of the active map)."""

    def start_mapping(self, actor: str) -> str:
        """Start a mapping run (the rover driven by teleop); return a sentence."""

    def finish_mapping(self, name: str, floor: str, actor: str, save: bool) -> str:
        """End the mapping run: with ``save``, keep it as the new map ``name`` on ``floor``."""


@dataclass
class MapsAccess:
    """The map library and its host, as the dashboard's ``/api/maps`` handlers see them.

    Attributes:
        library: the maps on disk.
        control: the host (None: switching, mapping and reloading are not available, e.g. an
            App a test or scenario built directly).
        active: the map this App runs on.
    """

    library: MapLibrary
    control: MapControl | None
    active: str


def config_for(cfg: Config, library: MapLibrary, name: str, *, mapping: bool = False,
               web_port: int | None = None) -> Config:
    """``cfg`` for an App on map ``name``: its YAML, its simulated building (the map itself
    when it has none), and its paths, tours and schedules inside the map's directory (the
    first, seeded map keeps those of ``data_dir``: ``keeps_data_dir``). With
    ``mapping``: a mapping run (``localization.mode = "map"``) saving to the scratch map."""
    folder = f"{cfg.maps.directory}/{name}"
    world = library.world_yaml(name) or library.map_yaml(name)
    loc: dict[str, Any] = {"map_yaml": str(library.map_yaml(name))}
    if mapping:
        loc.update(mode="map", mapping_out=f"{cfg.maps.directory}/{MAPPING_SCRATCH}")
    update: dict[str, Any] = {
        "localization": cfg.localization.model_copy(update=loc),
        "sim": cfg.sim.model_copy(update={"world": str(world)}),
    }
    if not library.meta(name).get("keeps_data_dir"):  # the seeded map keeps data_dir's
        update["bt"] = cfg.bt.model_copy(update={"paths_file": f"{folder}/paths.json"})
        update["tours"] = cfg.tours.model_copy(update={
            "file": f"{folder}/tours.json", "schedules_file": f"{folder}/schedules.json"})
    if web_port is not None:
        update["web"] = cfg.web.model_copy(update={"port": web_port})
    return cfg.model_copy(update=update)
