"""List the nodes of the live graph, embedded and rclpy alike: ``list`` (as ros2 node list)."""

from __future__ import annotations

import argparse
import time

#: how long to listen for ros_discovery_info before answering [s]
DISCOVERY_S = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="node_verb", metavar="<list>")
    sub.required = True
    p_list = sub.add_parser("list", help="nodes in the graph (read from ros_discovery_info)")
    p_list.add_argument("--wait", type=float, default=DISCOVERY_S, help="seconds to listen for discovery")
    p_list.add_argument("-a", "--all", action="store_true",
                        help="also hidden nodes (name starting with '_', e.g. ros2cli's daemon), as ros2 node list -a")


def graph_nodes(wait_s: float) -> list[str]:
    """Fully qualified names of the nodes on the domain, sorted (a name shared by two nodes twice)."""
    from taiji2_runtime.dds_rclpy.context import Context

    context = Context()
    context.init(["taiji2"])
    try:
        context.participant()
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            time.sleep(0.05)  # discovery arrives on Cyclone's threads; nothing to spin here
        return [node.fqn for node in context.graph_nodes()]
    finally:
        context.try_shutdown()


def is_hidden(fqn: str) -> bool:
    """A hidden node, as rclpy and ros2cli define it: its name (not its namespace) starts with ``_``."""
    return fqn.rsplit("/", 1)[-1].startswith("_")


def main(args: argparse.Namespace) -> int:
    for name in graph_nodes(args.wait):
        if args.all or not is_hidden(name):
            print(name)
    return 0
