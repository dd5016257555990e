"""A relay's publisher that holds its messages until its expected subscribers have matched it.

The link nodes relay data as it comes (packetizer -> space_link -> ground_receiver -> estimators, recorder,
monitors), on reliable *volatile* topics: what a writer sends before a reader has matched it never reaches
that reader. The simulator waits for its subscriber (``wait_for_subscribers``), but a relay further down
that is slower to start (a loaded machine, a profiler) matched its readers only after the first bursts had
gone: a ground receiver started late lost the first 1,100 s of a run and the command acknowledgements
(found with the receiver under cProfile: 59,654 samples used instead of 70,638, every table "lost on uplink").

Each relay output therefore takes a minimum subscriber count (its node's ``wait_for_subscribers``, default
0: no wait, as before) and holds what it is given until that many readers have matched the writer, then
sends the held messages in order and everything after directly. The count is the writer's own matched
readers, so it holds whatever the other processes' discovery timing. It holds only at the start: a reader
that goes away later (a restarting node) is not waited for again.
"""

from __future__ import annotations

from typing import Any

from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.ros import rclpy

__all__ = ["SubscribedPublisher"]


class SubscribedPublisher:
    """``publisher`` holding its messages until ``minimum`` subscribers have matched it (module docstring).

    Parameters
    ----------
    publisher : rclpy.publisher.Publisher
        The writer (its QoS should keep all: held messages are sent back to back).
    minimum : int
        Subscribers to wait for (0: publish at once).
    """

    def __init__(self, publisher: Any, minimum: int) -> None:
        if minimum < 0:
            raise ValueError(f"wait_for_subscribers: a count >= 0, got {minimum}")
        self.publisher = publisher
        self.minimum = int(minimum)
        self.held: list[Any] = []
        self.open = self.minimum == 0

    def publish(self, msg: Any) -> None:
        """Publish ``msg``, or hold it (in order) while the subscribers are not all there."""
        if not self.open and not self.release():
            self.held.append(msg)
            return
        self.publisher.publish(msg)

    def release(self) -> bool:
        """Whether the subscribers are there; when they first are, send what was held. For a timer as well:
        the last messages of a run must not wait for a next ``publish`` that never comes."""
        if not self.open:
            if self.publisher.get_subscription_count() < self.minimum:
                return False
            self.open = True
            held, self.held = self.held, []
            for msg in held:
                self.publisher.publish(msg)
        return True


def hold_until_subscribed(node: Any, publishers: list[Any], topics: str) -> list[SubscribedPublisher]:
    """Declare ``node``'s read-only ``wait_for_subscribers`` (one count per publisher, in the order ``topics``
    names them) and wrap ``publishers``; a steady 20-Hz timer releases what they hold until every one is open.

    Raises
    ------
    ValueError
        If the parameter does not give one count >= 0 per publisher.
    """
    counts = list(node.declare_parameter("wait_for_subscribers", [0] * len(publishers), read_only(
        f"hold the output until this many subscribers have matched each of {topics} (0: publish at once)")).value)
    if len(counts) != len(publishers) or any(int(c) < 0 for c in counts):
        raise ValueError(f"wait_for_subscribers: expected {len(publishers)} counts >= 0 ({topics}), got {counts}")
    wrapped = [SubscribedPublisher(p, int(c)) for p, c in zip(publishers, counts, strict=True)]
    if all(w.open for w in wrapped):
        return wrapped
    steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
    timer: list[Any] = []

    def release() -> None:
        if all([w.release() for w in wrapped]):
            timer[0].cancel()
            node.get_logger().info(f"every subscriber waited for has matched ({topics}): publishing")

    timer.append(node.create_timer(0.05, release, clock=steady))
    return wrapped
