"""Creation of DDS topics, safe against a race in cyclonedds-python 11.0.1's ``Topic()``.

``Topic()`` (native ``ddspy_topic_create``) ends with ``init_cdrstream_descriptor``, which walks
Cyclone's type library (``ddsi_topic_descriptor_from_type`` -> ``ddsi_type_resolved_locked``: the
``typedeps`` AVL tree of the whole domain) *without* the type-library lock. Cyclone's own threads
change that tree at the same time: deleting a participant hands its readers and writers to the
garbage-collector thread, which drops their type references a moment later, and a type whose last
reference goes is freed with its dependency records. A ``Topic()`` of the next context, created
within that moment, then read a freed tree node (a segmentation fault in
``ddsi_typeid_compare_src_dep`` under ``Topic()``) or missed a dependency (``DDSException:
BAD_PARAMETER`` from ``Topic()``).

Two measures keep that tree still while ``Topic()`` walks it:

* every data type used by a topic is also *anchored*: one topic of that type in a participant of
  the domain that lives as long as the process. Its type then never loses its last reference, so
  no participant deletion frees a node of the tree (a type already in the library gains and loses
  references without any change to the tree). The anchor topics have no reader or writer and
  topic discovery is off by default, so nothing of them is sent; the anchor participant is one
  more participant on the wire, without nodes;
* all topics of the process are created under one lock, so that two threads never add types to
  the library while the other walks it.

Left open: a remote endpoint whose type this process never used adds that type to the library
from Cyclone's discovery thread (and removes it when the endpoint goes); a ``Topic()`` at the
same moment is still exposed, as it is in any cyclonedds-python 11.0.1 program.
"""

from __future__ import annotations

import threading

from cyclonedds.domain import DomainParticipant
from cyclonedds.topic import Topic

_lock = threading.Lock()
#: domain id -> (anchor participant, {data type: anchor topic})
_anchors: dict[int, tuple[DomainParticipant, dict[type, Topic]]] = {}


def create_topic(participant: DomainParticipant, dds_name: str, dds_type: type) -> Topic:
    """``Topic(participant, dds_name, dds_type)``, with ``dds_type`` anchored in the participant's domain.

    Raises
    ------
    DDSException
        As ``Topic()`` (e.g. ``dds_name`` already used with another type in ``participant``).
    """
    with _lock:
        domain_id = participant.get_domain_id()
        if domain_id not in _anchors:
            _anchors[domain_id] = (DomainParticipant(domain_id), {})
        anchor, anchored = _anchors[domain_id]
        if dds_type not in anchored:
            anchored[dds_type] = Topic(anchor, f"taiji2_type_anchor_{len(anchored)}", dds_type)
        return Topic(participant, dds_name, dds_type)


def anchored_types(domain_id: int) -> list[type]:
    """The data types anchored in domain ``domain_id`` so far (for tests)."""
    with _lock:
        return list(_anchors[domain_id][1]) if domain_id in _anchors else []
