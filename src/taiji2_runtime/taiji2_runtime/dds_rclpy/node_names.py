"""Graph-wide uniqueness of node names across processes (no __future__ annotations: Cyclone resolves them).

Every node announces ``(fully qualified name, pid, start time)`` on a keyed, transient-local DDS
topic outside the ROS ``rt/`` namespace (so it never shows as a ROS topic). When two live nodes
share a name, the one that started later is the duplicate: its context shuts down with the reason,
and ``spin`` raises :class:`NodeNameNonUniqueError`.
"""


import os
import time
from dataclasses import dataclass

import cyclonedds.idl.types as idl_types
from cyclonedds.core import Policy, Qos
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import key
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

ANNOUNCEMENT_TOPIC = "taiji2_node_names"
_ALIVE = 16  # DDS_IST_ALIVE


@dataclass
class NodeAnnouncement(IdlStruct, typename="taiji2_runtime::NodeAnnouncement"):
    """A node's claim on its name (keyed by name and process, so each node is one instance)."""

    fqn: str
    pid: idl_types.int64
    start_ns: idl_types.int64
    key("fqn")
    key("pid")


def _qos() -> Qos:
    return Qos(Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal, Policy.History.KeepLast(1))


class NodeNameRegistry:
    """Announces this process's nodes and spots an earlier node elsewhere with the same name."""

    def __init__(self, participant: object) -> None:
        self._topic = Topic(participant, ANNOUNCEMENT_TOPIC, NodeAnnouncement)
        self._writer = DataWriter(participant, self._topic, _qos())
        self._reader = DataReader(participant, self._topic, _qos())
        self._mine: dict[str, NodeAnnouncement] = {}
        self._others: dict[tuple[str, int], NodeAnnouncement] = {}

    def announce(self, fqn: str) -> None:
        sample = NodeAnnouncement(fqn=fqn, pid=os.getpid(), start_ns=time.time_ns())
        self._mine[fqn] = sample
        self._writer.write(sample)

    def withdraw(self, fqn: str) -> None:
        sample = self._mine.pop(fqn, None)
        if sample is not None:
            self._writer.dispose(sample)

    def conflict(self) -> str | None:
        """A message naming the clash if one of this process's nodes is the later duplicate."""
        for sample in self._reader.take(N=256):
            # a disposed or unregistered instance arrives as an InvalidSample holding only the key
            keyed = getattr(sample, "key_sample", sample)
            ident = (keyed.fqn, keyed.pid)
            if sample.sample_info.instance_state == _ALIVE and hasattr(sample, "start_ns"):
                self._others[ident] = sample
            else:
                self._others.pop(ident, None)
        for (fqn, pid), other in self._others.items():
            mine = self._mine.get(fqn)
            if mine is None or pid == os.getpid():
                continue
            if (other.start_ns, other.pid) < (mine.start_ns, mine.pid):
                return f"a node named {fqn!r} already runs in the graph (process {pid}); node names must be unique"
        return None
