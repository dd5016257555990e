"""Read and set parameters of live nodes, embedded or rclpy: ``list``, ``get``, ``set`` (as ros2 param)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

#: seconds to wait for a node's parameter service to appear and answer
DEFAULT_TIMEOUT_S = 5.0
_TYPE_WORDS = {1: "Boolean", 2: "Integer", 3: "Double", 4: "String", 5: "Byte", 6: "Boolean", 7: "Integer",
               8: "Double", 9: "String"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="param_verb", metavar="<list|get|set>")
    sub.required = True
    p_list = sub.add_parser("list", help="parameter names of a node (of every node without one)")
    p_list.add_argument("node_name", nargs="?", help="node to list (default: every node)")
    p_get = sub.add_parser("get", help="a parameter's value")
    p_get.add_argument("node_name", help="node, e.g. /spacecraft_sim")
    p_get.add_argument("parameter_name", help="parameter, e.g. seed")
    p_set = sub.add_parser("set", help="set a parameter (the value is read as YAML, as ros2 param does)")
    p_set.add_argument("node_name", help="node, e.g. /maneuver_commander")
    p_set.add_argument("parameter_name", help="parameter, e.g. lookahead_s")
    p_set.add_argument("value", help="new value, YAML syntax as ros2 param set (e.g. 2.0, true, [1, 2])")
    for p in (p_list, p_get, p_set):
        p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, help="seconds to wait for the node")


def _fqn(node_name: str) -> str:
    return node_name if node_name.startswith("/") else "/" + node_name


def _call(context: Any, srv: str, node: str, service: str, timeout_s: float, **fields: Any) -> Any:
    from taiji2_runtime.dds_rclpy.service_client import ServiceClient

    client = ServiceClient(context, f"rcl_interfaces/srv/{srv}", f"{node}/{service}")
    try:
        return client.call(client.request_class(**fields), timeout_s)
    except TimeoutError as exc:
        raise LookupError(f"node {node!r}: {exc}") from None


def _describe_value(value: Any) -> str:
    from taiji2_runtime.dds_rclpy.parameter import Parameter
    from taiji2_runtime.dds_rclpy.parameter_services import VALUE_FIELD

    kind = Parameter.Type(value.type)
    if kind == Parameter.Type.NOT_SET:
        return "Parameter not set."
    field = getattr(value, VALUE_FIELD[kind])
    word = _TYPE_WORDS[int(kind)]
    if kind.name.endswith("ARRAY"):
        return f"{word} values are: {list(field)}"
    return f"{word} value is: {field}"


def _parameter_msg(name: str, text: str) -> Any:
    import yaml

    from taiji2_runtime.dds_rclpy.parameter import Parameter
    from taiji2_runtime.dds_rclpy.parameter_services import to_parameter_value
    from taiji2_runtime.interfaces import message_class

    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = text
    try:
        parameter = Parameter(name, value=value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"value {text!r} of parameter {name!r}: {exc}") from None
    return message_class("rcl_interfaces/msg/Parameter")(name=name, value=to_parameter_value(parameter))


def _run(context: Any, args: argparse.Namespace) -> int:
    if args.param_verb == "list":
        if args.node_name:
            nodes = [_fqn(args.node_name)]
        else:
            from taiji2_runtime.cli.node import graph_nodes

            nodes = sorted(set(graph_nodes(min(args.timeout, 1.0))))
        for node in nodes:
            result = _call(context, "ListParameters", node, "list_parameters", args.timeout).result
            if not args.node_name:
                print(f"{node}:")
            for name in sorted(result.names):
                print(f"  {name}")
        return 0
    node = _fqn(args.node_name)
    if args.param_verb == "get":
        values = _call(context, "GetParameters", node, "get_parameters", args.timeout,
                       names=[args.parameter_name]).values
        print(_describe_value(values[0]) if values else "Parameter not set.")
        return 0
    results = _call(context, "SetParameters", node, "set_parameters", args.timeout,
                    parameters=[_parameter_msg(args.parameter_name, args.value)]).results
    if results and results[0].successful:
        print("Set parameter successful")
        return 0
    reason = results[0].reason if results else "no result"
    print(f"error: taiji2 param set: {node} {args.parameter_name}: {reason}", file=sys.stderr)
    return 1


def main(args: argparse.Namespace) -> int:
    from taiji2_runtime.dds_rclpy.context import Context

    context = Context()
    context.init(["taiji2"])
    try:
        return _run(context, args)
    finally:
        context.try_shutdown()
