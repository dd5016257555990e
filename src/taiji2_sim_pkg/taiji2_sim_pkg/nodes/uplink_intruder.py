"""uplink_intruder: an attacker on the uplink, for testing the spacecraft's command security (docs/security.md).

Listens to what the spacecraft receives (``/onboard/link/tc``: the genuine TC frames, in the clear as SDLS
authentication mode leaves them) and, once it has seen the first genuine burst, transmits its own frames to
the spacecraft on the same topic (an intruder with a transmitter of its own, not through the ground station):
the attacks of :mod:`taiji2_sim_pkg.uplink_attacks`, each arriving after the genuine frame it is modelled on.
Its own account (what it sent, per kind, and the refusal each frame should meet) goes on
``/taiji2/sim/intruder_report`` (latched JSON; evaluation only, like ``/taiji2/sim/``). It never has an active
key; for ``revoked`` it signs with ``leaked_key_file`` (a key file of keys the operators revoked).
Parameters: ``config/uplink_intruder.yaml``.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from typing import Any

from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.packets.sdls_keys import ACTIVE, KeyTable, SecurityAssociation, load_key_file
from taiji2_runtime.packets.tc_frame import FrameError
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.uplink_attacks import ATTACK_KINDS, AttackFrame, build_attacks

REPORT_TOPIC = "/taiji2/sim/intruder_report"


class UplinkIntruder(rclpy.node.Node):
    """The intruder (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("uplink_intruder", **node_kwargs)
        dp = self.declare_parameter
        leaked_file = dp("leaked_key_file", "", read_only(
            "a key file of revoked keys the intruder holds (the revoked attack); empty: none")).value
        every = [k for k in ATTACK_KINDS if leaked_file or k != "revoked"]
        self._kinds = list(dp("attacks", every, read_only(
            f"attack kinds of {', '.join(ATTACK_KINDS)} (default: all; revoked only with leaked_key_file)")).value)
        unknown = sorted(set(self._kinds) - set(ATTACK_KINDS))
        if unknown:
            raise ValueError(f"attacks: unknown {unknown}; choose from {', '.join(ATTACK_KINDS)}")
        self._instances = int(dp("instances", 3, read_only("frames per attack kind")).value)
        self._flood = int(dp("flood_frames", 50, read_only("frames of the garbage flood")).value)
        self._seed = int(dp("seed", 0, read_only("seed of the intruder's random choices")).value)
        # the leaked keys, as the intruder holds them (its copy has no notion of their state onboard)
        self._leaked = (KeyTable(SecurityAssociation(sa.spi, sa.key, ACTIVE) for sa in load_key_file(leaked_file))
                        if leaked_file else None)
        if "revoked" in self._kinds and not self._leaked:
            raise ValueError("attacks: revoked needs leaked_key_file (a key file of revoked keys)")
        qos = lt.reliable_all()
        self._sent: list[AttackFrame] = []
        self._tc_pub = self.create_publisher(messages.taiji2_msgs.SpacePackets, lt.ONBOARD_TC, qos)
        self._report_pub = self.create_publisher(messages.std_msgs.String, REPORT_TOPIC, lt.latched())
        self.create_subscription(messages.taiji2_msgs.SpacePackets, lt.ONBOARD_TC, self._on_uplink, qos)
        self._publish_report()

    def _on_uplink(self, msg: Any) -> None:
        if self._sent or not msg.times_ns:
            return  # attacks once, after the first genuine burst (its own bursts come back here too)
        try:
            frames = lt.split_tc_frames(msg)
        except (ValueError, FrameError) as exc:
            self.get_logger().warn(f"uplink burst not understood: {exc}")
            return
        self._sent = build_attacks(frames, [int(t) for t in msg.times_ns], self._kinds, self._leaked,
                                   instances=self._instances, flood=self._flood, seed=self._seed)
        self._sent.sort(key=lambda a: a.arrival_ns)
        self._tc_pub.publish(lt.burst([a.frame for a in self._sent], [a.arrival_ns for a in self._sent], 0))
        self._publish_report()
        self.get_logger().info(f"sent {len(self._sent)} frames: " + ", ".join(
            f"{k} {n}" for k, n in Counter(a.kind for a in self._sent).items()))

    def report(self) -> dict[str, Any]:
        """What it sent: frames per kind and per expected refusal, and the arrival span [s]."""
        return {"attacks": self._kinds, "frames": len(self._sent),
                "sent": dict(Counter(a.kind for a in self._sent)),
                "expected_refusals": dict(Counter(a.expected for a in self._sent)),
                "arrival_s": [self._sent[0].arrival_ns / 1e9, self._sent[-1].arrival_ns / 1e9] if self._sent else []}

    def _publish_report(self) -> None:
        self._report_pub.publish(messages.std_msgs.String(data=json.dumps(self.report())))


def main(args: Sequence[str] | None = None) -> int:
    return run_node(UplinkIntruder, args)


if __name__ == "__main__":
    raise SystemExit(main())
