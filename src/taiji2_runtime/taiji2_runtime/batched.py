"""Subscriptions that take up to a batch of queued messages per callback, on rclpy as on the embedded runtime.

rclpy's executors take one message per subscription per wait-set pass, and a pass costs far more than a
message (every entity of the node is waited on again): an estimator fed at 100x real time spent most of its
time there (``benchmarks/bench_estimator_nodes.py``). A batched subscription's callback, once called, also
takes what is already queued on the same subscription, up to ``batch`` messages, and hands each to the
user's callback in order. The embedded runtime's executor already drains readers in batches of 64, so there
it is a plain subscription.

Keep ``batch`` small where several streams are aligned by stamp: a stream drained ahead of the others by
``batch`` samples is at most that far ahead in data time.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from taiji2_runtime.ros import RUNTIME

#: messages taken per callback at most (16 samples = 1.6 s of a 10-Hz stream)
DEFAULT_BATCH = 16


def create_batched_subscription(node: Any, msg_type: Any, topic: str, callback: Callable[[Any], None],
                                qos: Any, batch: int = DEFAULT_BATCH) -> Any:
    """``node.create_subscription(msg_type, topic, callback, qos)`` taking up to ``batch`` messages per call."""
    if RUNTIME != "rclpy" or batch <= 1:
        return node.create_subscription(msg_type, topic, callback, qos)
    holder: list[Any] = []

    def take_batch(first: Any) -> None:
        callback(first)
        sub = holder[0]
        for _ in range(batch - 1):
            try:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
            except Exception:  # destroyed meanwhile (shutdown), or an rclpy without this API: one at a time
                return
            if taken is None:
                return
            callback(taken[0])

    subscription = node.create_subscription(msg_type, topic, take_batch, qos)
    holder.append(subscription)
    return subscription
