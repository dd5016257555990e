"""Topics and types of the raw-data contract (``shared/design/interfaces.md``), fixed by design."""

from __future__ import annotations

STAR_TRACKER_TOPIC = "/taiji2/star_tracker"
GRS_TOPICS = ("/taiji2/grs1/voltages", "/taiji2/grs2/voltages")
COMMAND_TOPIC = "/taiji2/maneuver/command"
CLOCK_TOPIC = "/clock"
PROVENANCE_TOPIC = "/taiji2/sim/provenance"

STAR_TRACKER_TYPE = "taiji2_msgs/msg/StarTracker"
GRS_TYPE = "taiji2_msgs/msg/GrsVoltages"
COMMAND_TYPE = "geometry_msgs/msg/WrenchStamped"
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"

#: ``{topic: type}`` of the raw topics every experiment bag holds.
RAW_TOPICS: dict[str, str] = {
    STAR_TRACKER_TOPIC: STAR_TRACKER_TYPE,
    GRS_TOPICS[0]: GRS_TYPE,
    GRS_TOPICS[1]: GRS_TYPE,
    COMMAND_TOPIC: COMMAND_TYPE,
}
#: header.frame_id the contract prescribes per raw topic.
RAW_FRAME_IDS: dict[str, str] = {
    STAR_TRACKER_TOPIC: "crf",
    GRS_TOPICS[0]: "tmrf1",
    GRS_TOPICS[1]: "tmrf2",
    COMMAND_TOPIC: "crf",
}
#: grs_id the contract prescribes per GRS topic.
GRS_IDS: dict[str, int] = {GRS_TOPICS[0]: 1, GRS_TOPICS[1]: 2}
