"""The Cyclone DDS configuration of the embedded runtime, and the one a mixed graph shares (standard library only).

ROS 2 nodes (rmw_cyclonedds_cpp), the ros2 CLI and its daemon, and embedded-runtime nodes see each other
fully only under one configuration: ``export CYCLONEDDS_URI="$(taiji2 --print-cyclonedds-config)"`` in every
shell of the graph (README, "On a ROS 2 machine"). With different ones (rmw_cyclonedds_cpp's default is
multicast discovery, the embedded runtime's loopback unicast), discovery works in one
direction only: data flow, but service replies (``ros2 param``) are lost and a daemon shows part of the graph.
"""

from __future__ import annotations

import os

#: Highest participant index probed by unicast discovery (participants per host).
MAX_PARTICIPANTS_PER_HOST = 60

DEFAULT_CYCLONEDDS_CONFIG = f"""<CycloneDDS><Domain Id="any">
  <General>
    <Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>
    <AllowMulticast>false</AllowMulticast>
  </General>
  <Discovery>
    <ParticipantIndex>auto</ParticipantIndex>
    <MaxAutoParticipantIndex>{MAX_PARTICIPANTS_PER_HOST}</MaxAutoParticipantIndex>
    <Peers><Peer address="127.0.0.1"/></Peers>
  </Discovery>
  <Internal>
    <Watermarks><WhcHigh>32kB</WhcHigh></Watermarks>
  </Internal>
</Domain></CycloneDDS>"""


def effective_cyclonedds_config() -> str:
    """What the embedded runtime runs with: ``CYCLONEDDS_URI`` when set, else :data:`DEFAULT_CYCLONEDDS_CONFIG`
    on one line (a value for ``export CYCLONEDDS_URI=...``)."""
    uri = os.environ.get("CYCLONEDDS_URI", "").strip()
    return uri or "".join(line.strip() for line in DEFAULT_CYCLONEDDS_CONFIG.splitlines())
