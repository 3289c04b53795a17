"""``rmw_zenoh``'s naming on Zenoh: data key expressions, liveliness tokens, QoS strings and
publication attachments (``rmw_zenoh/docs/design.md``).

* Data: ``<domain_id>/<fully qualified topic, no leading slash>/<DDS type name>/<type hash>``,
  e.g. ``0/r1/scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_64c1…``.
* Liveliness tokens (the ROS graph): a node
  ``@ros2_lv/<domain>/<session id>/<node id>/<node id>/NN/<enclave>/<namespace>/<node>`` and
  each publisher ``@ros2_lv/<domain>/<session id>/<node id>/<entity id>/MP/<enclave>/
  <namespace>/<node>/<topic>/<DDS type name>/<type hash>/<qos>``, where a name is *mangled* by
  turning every ``/`` into ``%`` (an empty one is ``%``).
* QoS: ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
  <liveliness>,<lease s>,<ns>``, each value left empty when it equals ``rmw_zenoh``'s default
  (reliable, volatile, keep-last 42, infinite durations, automatic liveliness); the enum values
  are ``rmw/types.h``'s (reliable 1, best effort 2; transient local 1, volatile 2; keep last 1).
* Attachment of every publication: sequence number (int64 LE), source time in ns since the
  UNIX epoch (int64 LE), the GID's length (one byte, 16) and the publisher's 16-byte GID.
"""

from __future__ import annotations

import hashlib
import struct
from dataclasses import dataclass

from curio.fleet.ros2.msgs import dds_type_name, type_hash

__all__ = ["Qos", "attachment", "gid_of", "mangle", "node_token", "publisher_token",
           "qos_keyexpr", "topic_keyexpr"]

ADMIN_SPACE = "@ros2_lv"
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2
KEEP_LAST = 1
DEFAULT_DEPTH = 42


@dataclass(frozen=True)
class Qos:
    """A publisher's QoS (only what differs from ``rmw_zenoh``'s default shows in tokens)."""

    reliability: int = RELIABLE
    durability: int = VOLATILE
    history: int = KEEP_LAST
    depth: int = DEFAULT_DEPTH


def qos_keyexpr(q: Qos) -> str:
    """The compact QoS string of a liveliness token."""
    def val(value: int, default: int) -> str:
        return "" if value == default else str(value)

    return (f"{val(q.reliability, RELIABLE)}:{val(q.durability, VOLATILE)}:"
            f"{val(q.history, KEEP_LAST)},{val(q.depth, DEFAULT_DEPTH)}:,:,:,,")


def mangle(name: str) -> str:
    """Every ``/`` as ``%``; an empty name as ``%``."""
    return name.replace("/", "%") if name else "%"


def _fqn(namespace: str, topic: str) -> str:
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return f"{ns}/{topic.strip('/')}"


def topic_keyexpr(domain_id: int, namespace: str, topic: str, type_name: str) -> str:
    """The key a topic's samples are put on."""
    fqn = _fqn(namespace, topic).strip("/")
    return f"{domain_id}/{fqn}/{dds_type_name(type_name)}/{type_hash(type_name)}"


def node_token(domain_id: int, zid: str, node_id: int, namespace: str, node: str,
               enclave: str = "") -> str:
    """A node's liveliness token."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return (f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{node_id}/NN/{mangle(enclave)}/"
            f"{mangle(ns)}/{node}")


def publisher_token(domain_id: int, zid: str, node_id: int, entity_id: int, namespace: str,
                    node: str, topic: str, type_name: str, qos: Qos, enclave: str = "") -> str:
    """A publisher's liveliness token."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return (f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{entity_id}/MP/{mangle(enclave)}/"
            f"{mangle(ns)}/{node}/{mangle(_fqn(namespace, topic))}/{dds_type_name(type_name)}/"
            f"{type_hash(type_name)}/{qos_keyexpr(qos)}")


def gid_of(token: str) -> bytes:
    """A 16-byte publisher GID derived from its liveliness token."""
    return hashlib.sha256(token.encode()).digest()[:16]


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """The attachment of one publication."""
    if len(gid) != 16:
        raise ValueError(f"a GID has 16 bytes, got {len(gid)}")
    return struct.pack("<qqB", seq, stamp_ns, 16) + gid
