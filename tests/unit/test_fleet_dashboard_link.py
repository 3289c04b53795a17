"""The rover's dashboard address for the fleet page's link: the configured one, none on the
loopback, ``web.host`` when it is an address, else this machine's address towards the fleet
(the local end of a route to a numeric ``fleet.connect`` endpoint) or ``<hostname>.local``."""

from __future__ import annotations

import socket

from curio.core.config import load_config
from curio.fleet.wiring import dashboard_address


def _address(*overrides: str) -> str:
    return dashboard_address(load_config(None, list(overrides)), 8080)


def test_configured_loopback_and_explicit_addresses() -> None:
    assert _address('fleet.dashboard_url="http://guide-1.museum:8080/"') == \
        "http://guide-1.museum:8080/"
    assert _address('web.host="127.0.0.1"') == ""          # nobody else could open it
    assert _address('web.host="192.168.4.20"') == "http://192.168.4.20:8080/"
    assert _address('web.host="fe80::1"') == "http://[fe80::1]:8080/"
    assert _address('web.host="guide-1.lan"') == "http://guide-1.lan:8080/"


def test_on_every_interface_the_address_towards_the_fleet() -> None:
    mdns = f"http://{socket.gethostname().split('.')[0].lower()}.local:8080/"
    assert _address('web.host="0.0.0.0"') == mdns           # no endpoint to route towards
    assert _address('web.host="0.0.0.0"', 'fleet.connect=["tcp/127.0.0.1:7447"]') == mdns
    assert _address('web.host="0.0.0.0"', 'fleet.connect=["tcp/router.site:7447"]') == mdns
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("198.51.100.7", 7447))
            local = probe.getsockname()[0]
        except OSError:  # no route on this machine: the name is what is left
            local = None
    expected = f"http://{local}:8080/" if local else mdns
    assert _address('web.host="0.0.0.0"', 'fleet.connect=["tcp/198.51.100.7:7447"]') == expected
