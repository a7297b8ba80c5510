"""Publishing as a ROS 2 node under rmw_zenoh does, with a plain Zenoh session (no ROS).

What rmw_zenoh_cpp does (its docs/design.md and liveliness_utils.cpp, attachment_helpers.cpp,
rmw_publisher_data.cpp; the layout of the Jazzy, Kilted and Rolling releases, Zenoh 1.x):

Data key expression: ``<domain_id>/<fully qualified topic without the leading />/<DDS type
name>/<RIHS01 type hash>``, e.g. ``0/navd/imu/sensor_msgs::msg::dds_::Imu_/RIHS01_7d9a...``.
Payload: the CDR message (:mod:`navd.io.ros2.messages`).

Attachment of every sample (Zenoh's ext serializer: little-endian integers, LEB128 sequence
lengths), 33 bytes:

    int64 sequence number (1 for the first sample of a publisher)
    int64 source timestamp, ns since the UNIX epoch (host clock at publish)
    LEB128 length 16, then the 16-byte publisher GID

Liveliness tokens, declared while the entity exists (``ros2 node list`` / ``topic list``
read them; the GID is XXH3-128 of the publisher's token, low 64 bits first, little-endian):

    node       @ros2_lv/<domain>/<zid>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<node>
    publisher  @ros2_lv/<domain>/<zid>/<node_id>/<entity_id>/MP/<enclave>/<namespace>/<node>/
               <topic>/<DDS type name>/<type hash>/<qos>

with every ``/`` inside a name written ``%`` (the root namespace and the default enclave
``/`` become ``%``; ``/navd/imu`` becomes ``%navd%imu``), ``<zid>`` the Zenoh session id as
Zenoh prints it, and ``<qos>`` rmw_zenoh's compact QoS where a field equal to its default
(reliable, volatile, keep-last 42, infinite deadline/lifespan/lease, automatic liveliness) is
left empty: reliable + volatile + keep-last 10 is ``::,10:,:,:,,``.

Not supported: Humble (no type hashes, 24-byte GIDs) and the pre-Zenoh-1.0 Iron/early-Jazzy
development snapshots (key/value attachments).
"""

from __future__ import annotations

import contextlib
import struct
import time
from typing import Any

import xxhash
import zenoh

from navd.io.ros2.msgdefs import TYPE_HASHES, dds_type_name
from navd.io.ros2.names import fully_qualified, validate_name, validate_namespace

__all__ = [
    "ADMIN_SPACE",
    "DEFAULT_QOS",
    "GID_SIZE",
    "Ros2Node",
    "Ros2Publisher",
    "attachment",
    "entity_gid",
    "fully_qualified",
    "mangle",
    "node_token",
    "publisher_token",
    "topic_key",
    "validate_name",
    "validate_namespace",
]

ADMIN_SPACE = "@ros2_lv"
DEFAULT_QOS = "::,10:,:,:,,"  # reliable, volatile, keep last 10
GID_SIZE = 16

def mangle(name: str) -> str:
    """A name as one liveliness key chunk: each ``/`` becomes ``%``."""
    return name.replace("/", "%")


def topic_key(domain_id: int, fq_topic: str, type_name: str, type_hash: str = "") -> str:
    """``type_hash``: default, navd's shipped hash of ``type_name``."""
    h = type_hash or TYPE_HASHES[type_name]
    return f"{domain_id}/{fq_topic.strip('/')}/{dds_type_name(type_name)}/{h}"


def node_token(domain_id: int, zid: str, node_id: int, enclave: str, namespace: str,
               node: str) -> str:
    return (f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{node_id}/NN/{mangle(enclave)}/"
            f"{mangle(namespace)}/{node}")


def publisher_token(domain_id: int, zid: str, node_id: int, entity_id: int, enclave: str,
                    namespace: str, node: str, fq_topic: str, type_name: str,
                    qos: str = DEFAULT_QOS, type_hash: str = "") -> str:
    h = type_hash or TYPE_HASHES[type_name]
    return (f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{entity_id}/MP/{mangle(enclave)}/"
            f"{mangle(namespace)}/{node}/{mangle(fq_topic)}/{dds_type_name(type_name)}/"
            f"{h}/{qos}")


def entity_gid(token: str) -> bytes:
    """The 16-byte GID rmw_zenoh derives from an entity's liveliness key expression."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


_ATTACH = struct.Struct("<qqB16s")


def attachment(seq: int, source_ns: int, gid: bytes) -> bytes:
    """The 33-byte sample attachment (see the module docstring)."""
    return _ATTACH.pack(seq, source_ns, GID_SIZE, gid)


class Ros2Publisher:
    """One topic: a Zenoh publisher on the data key plus its liveliness token."""

    def __init__(self, session: Any, key: str, token: str, topic: str = "") -> None:
        self.topic = topic  # fully qualified ROS name, for logs
        self.key = key
        self.token_key = token
        self.gid = entity_gid(token)
        self.seq = 0
        # what rmw_zenoh declares for a reliable keep-last publisher (the QoS in the token)
        self._pub = session.declare_publisher(key, reliability=zenoh.Reliability.RELIABLE,
                                              congestion_control=zenoh.CongestionControl.DROP)
        try:
            self._token = session.liveliness().declare_token(token)
        except BaseException:
            self._pub.undeclare()
            raise

    def put(self, payload: bytes, source_ns: int | None = None) -> None:
        """Send one CDR sample (raises zenoh.ZError if Zenoh refuses it)."""
        self.seq += 1
        ts = time.time_ns() if source_ns is None else source_ns
        self._pub.put(payload, attachment=attachment(self.seq, ts, self.gid))

    def close(self) -> None:
        for ent in (self._token, self._pub):
            # session already closed: the peers see the entity leave anyway
            with contextlib.suppress(zenoh.ZError):
                ent.undeclare()


class Ros2Node:
    """A ROS 2 node's graph presence on an existing Zenoh session: its NN token and the
    publishers made with :meth:`publisher`.  Closing undeclares them (``ros2 topic list``
    stops showing the topics); the session stays open, it belongs to the caller."""

    def __init__(self, session: Any, *, domain_id: int, namespace: str, node: str,
                 enclave: str = "/") -> None:
        err = validate_namespace(namespace) or validate_name(node)
        if err is not None:
            raise ValueError(err)
        self.session = session
        self.domain_id = domain_id
        self.namespace = namespace
        self.node = node
        self.enclave = enclave
        self.zid = str(session.zid())
        self.node_id = 0
        self._next_id = 1
        self.token_key = node_token(domain_id, self.zid, self.node_id, enclave, namespace, node)
        self._token = session.liveliness().declare_token(self.token_key)
        self.publishers: list[Ros2Publisher] = []

    def publisher(self, topic: str, type_name: str) -> Ros2Publisher:
        fq = fully_qualified(self.namespace, topic)
        token = publisher_token(self.domain_id, self.zid, self.node_id, self._next_id,
                                self.enclave, self.namespace, self.node, fq, type_name)
        self._next_id += 1
        pub = Ros2Publisher(self.session, topic_key(self.domain_id, fq, type_name), token, fq)
        self.publishers.append(pub)
        return pub

    def close(self) -> None:
        for p in self.publishers:
            p.close()
        self.publishers.clear()
        with contextlib.suppress(zenoh.ZError):
            self._token.undeclare()
