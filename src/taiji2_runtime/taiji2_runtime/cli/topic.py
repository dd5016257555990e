"""Inspect topics of the live graph: ``list``, ``echo <topic> [--once]``, ``hz <topic>`` (as ros2 topic)."""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections import deque
from typing import Any

_DISCOVERY_S = 0.6


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="topic_verb", metavar="<list|echo|hz>")
    sub.required = True
    p_list = sub.add_parser("list", help="topics in the graph")
    p_list.add_argument("-t", "--show-types", action="store_true", help="also show the message type")
    p_echo = sub.add_parser("echo", help="print messages of a topic as YAML")
    p_echo.add_argument("topic", help="topic name, e.g. /taiji2/star_tracker")
    p_echo.add_argument("message_type", nargs="?", help="e.g. geometry_msgs/msg/WrenchStamped (default: discover)")
    p_echo.add_argument("--once", action="store_true", help="print one message and exit")
    p_echo.add_argument("--qos-reliability", choices=("best_effort", "reliable"), default="best_effort",
                        help="reliability of the subscription (default best_effort, as ros2 topic echo)")
    p_echo.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the topic to appear")
    p_hz = sub.add_parser("hz", help="print the average publishing rate")
    p_hz.add_argument("topic", help="topic name, e.g. /taiji2/grs1/voltages")
    p_hz.add_argument("--window", "-w", type=int, default=100, help="window size in messages")
    p_hz.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the topic to appear")
    p_hz.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: never)")


def _msg_class(type_name: str) -> type:
    from taiji2_runtime.ros import messages

    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3:
        raise ValueError(f"invalid message type {type_name!r} (expected pkg/msg/Name)")
    try:
        return getattr(getattr(messages, parts[0]), parts[2])
    except (AttributeError, ImportError):
        raise LookupError(f"message type {type_name!r} is unknown") from None


def _topic_type(node: Any, topic: str, wait_s: float) -> str:
    from taiji2_runtime.ros import rclpy

    deadline = time.monotonic() + wait_s
    while True:
        for name, types in node.get_topic_names_and_types():
            if name == topic and types:
                return types[0]
        if time.monotonic() > deadline:
            raise LookupError(f"topic {topic!r} does not appear to be published yet (waited {wait_s:g} s)")
        rclpy.spin_once(node, timeout_sec=0.05)


class _Session:
    """rclpy init + a short-lived node for a CLI verb; always shut down on exit."""

    def __enter__(self) -> Any:
        from taiji2_runtime.ros import rclpy

        rclpy.init(args=["taiji2"])
        self.node = rclpy.create_node(f"taiji2_cli_{int(time.time() * 1e3) % 10**9}")
        return self.node

    def __exit__(self, *exc: object) -> None:
        from taiji2_runtime.ros import rclpy

        self.node.destroy_node()
        rclpy.try_shutdown()


def _spin(node: Any, until: Any) -> None:
    from taiji2_runtime.ros import rclpy

    try:
        while rclpy.ok() and not until():
            rclpy.spin_once(node, timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    except Exception as exc:
        if type(exc).__name__ != "ExternalShutdownException":
            raise


def cmd_list(args: argparse.Namespace) -> int:
    with _Session() as node:
        start = time.monotonic()
        _spin(node, lambda: time.monotonic() - start > _DISCOVERY_S)
        for name, types in node.get_topic_names_and_types():
            print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def _qos(reliability: str) -> Any:
    from taiji2_runtime.ros import rclpy

    qos = rclpy.qos
    policy = qos.ReliabilityPolicy.RELIABLE if reliability == "reliable" else qos.ReliabilityPolicy.BEST_EFFORT
    return qos.QoSProfile(depth=100, reliability=policy)


def cmd_echo(args: argparse.Namespace) -> int:
    import yaml

    from taiji2_runtime.interfaces import to_plain

    with _Session() as node:
        type_name = args.message_type or _topic_type(node, args.topic, args.wait)
        msg_class = _msg_class(type_name)
        count = [0]

        def on_msg(msg: Any) -> None:
            sys.stdout.write(yaml.safe_dump(to_plain(msg), sort_keys=False, default_flow_style=False))
            sys.stdout.write("---\n")
            sys.stdout.flush()
            count[0] += 1

        node.create_subscription(msg_class, args.topic, on_msg, _qos(args.qos_reliability))
        _spin(node, lambda: args.once and count[0] >= 1)
    return 0


def cmd_hz(args: argparse.Namespace) -> int:
    with _Session() as node:
        type_name = _topic_type(node, args.topic, args.wait)
        stamps: deque[float] = deque(maxlen=args.window + 1)
        state = {"last_print": time.monotonic(), "start": time.monotonic()}

        def on_msg(_msg: Any) -> None:
            stamps.append(time.monotonic())

        def report() -> bool:
            now = time.monotonic()
            if now - state["last_print"] >= 1.0:
                state["last_print"] = now
                if len(stamps) >= 2:
                    deltas = [b - a for a, b in zip(stamps, list(stamps)[1:], strict=False)]
                    mean = sum(deltas) / len(deltas)
                    std = math.sqrt(sum((d - mean) ** 2 for d in deltas) / len(deltas))
                    print(f"average rate: {1.0 / mean:.3f}\n\tmin: {min(deltas):.3f}s max: {max(deltas):.3f}s "
                          f"std dev: {std:.5f}s window: {len(deltas)}", flush=True)
                else:
                    print("no new messages", flush=True)
            return bool(args.duration) and now - state["start"] >= args.duration

        node.create_subscription(_msg_class(type_name), args.topic, on_msg, _qos("best_effort"))
        _spin(node, report)
    return 0


def main(args: argparse.Namespace) -> int:
    return {"list": cmd_list, "echo": cmd_echo, "hz": cmd_hz}[args.topic_verb](args)
