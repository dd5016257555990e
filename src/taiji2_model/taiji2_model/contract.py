"""Topics and types of the raw-data contract (``shared/design/interfaces.md``), fixed by design, and the
topics of the estimates and of the simulator's truth (``/taiji2/sim/``, which no estimator reads)."""

from __future__ import annotations

STAR_TRACKER_TOPIC = "/taiji2/star_tracker"
GRS_TOPICS = ("/taiji2/grs1/voltages", "/taiji2/grs2/voltages")
#: the GRS voltage topic of each GRS id
GRS_TOPIC_OF: dict[int, str] = {1: GRS_TOPICS[0], 2: GRS_TOPICS[1]}
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

# Estimates (the estimator nodes publish them; taiji2_msgs types).
#: scale factors G of each GRS id (taiji2_msgs/msg/ScaleFactorEstimate)
SCALE_FACTOR_ESTIMATE_TOPIC_OF: dict[int, str] = {g: f"/taiji2/estimates/grs{g}/scale_factors" for g in (1, 2)}
#: c.m. offset d of each GRS id (taiji2_msgs/msg/ComOffsetEstimate)
COM_OFFSET_ESTIMATE_TOPIC_OF: dict[int, str] = {g: f"/taiji2/estimates/grs{g}/com_offset" for g in (1, 2)}
#: d_1 - d_2 with its covariance (taiji2_msgs/msg/ComOffsetEstimate)
COM_OFFSET_DIFFERENCE_TOPIC = "/taiji2/estimates/com_offset_difference"
#: the scale-factor estimator's attitude filter's angular rate (geometry_msgs/msg/Vector3Stamped)
ANGULAR_RATE_ESTIMATE_TOPIC = "/taiji2/estimates/angular_rate"

# The simulator's truth, for evaluation only.
#: true G of each GRS id (taiji2_msgs/msg/ScaleFactorEstimate, zero covariance)
TRUE_SCALE_FACTOR_TOPIC_OF: dict[int, str] = {g: f"/taiji2/sim/grs{g}/scale_factors" for g in (1, 2)}
#: true d of each GRS id (taiji2_msgs/msg/ComOffsetEstimate, zero covariance)
TRUE_COM_OFFSET_TOPIC_OF: dict[int, str] = {g: f"/taiji2/sim/grs{g}/com_offset" for g in (1, 2)}
TRUE_ANGULAR_RATE_TOPIC = "/taiji2/sim/angular_rate"
TRUE_ANGULAR_ACCELERATION_TOPIC = "/taiji2/sim/angular_acceleration"
TRUE_ATTITUDE_TOPIC = "/taiji2/sim/attitude"
APPLIED_WRENCH_TOPIC = "/taiji2/sim/applied_wrench"
