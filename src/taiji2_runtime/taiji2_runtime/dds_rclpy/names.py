"""ROS 2 name validation and resolution (namespaces, private names, remapping)."""

from __future__ import annotations

import re

_NODE_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TOPIC_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class InvalidNameError(ValueError):
    """A node name, namespace or topic name breaks the ROS 2 naming rules."""


def validate_node_name(name: str) -> None:
    if not _NODE_NAME.match(name or ""):
        raise InvalidNameError(
            f"node name {name!r} is invalid: it must start with a letter or '_' and hold only "
            "letters, digits and '_'"
        )


def normalize_namespace(namespace: str | None) -> str:
    ns = (namespace or "/").strip()
    if not ns.startswith("/"):
        ns = "/" + ns
    if len(ns) > 1:
        ns = ns.rstrip("/")
    _validate_absolute(ns, "namespace", allow_root=True)
    return ns


def _validate_absolute(name: str, what: str, *, allow_root: bool = False) -> None:
    if name == "/" and allow_root:
        return
    tokens = name.split("/")[1:]
    if not tokens or any(not _TOPIC_TOKEN.match(t) for t in tokens):
        raise InvalidNameError(
            f"{what} {name!r} is invalid: tokens separated by '/' must start with a letter or '_' "
            "and hold only letters, digits and '_'"
        )


def expand_topic_name(topic: str, node_name: str, namespace: str) -> str:
    """Fully qualified topic name: ``~`` -> node's private namespace, relative -> node namespace."""
    if not topic:
        raise InvalidNameError("topic name must not be empty")
    if topic.startswith("~"):
        base = f"{namespace.rstrip('/')}/{node_name}"
        name = base + topic[1:]
    elif topic.startswith("/"):
        name = topic
    else:
        name = f"{namespace.rstrip('/')}/{topic}"
    _validate_absolute(name, "topic name")
    return name


def remap_topic_name(
    fqn: str, remaps: list[tuple[str | None, str, str]], node_name: str, namespace: str
) -> str:
    """Apply the first matching ``-r from:=to`` rule (rules addressed to other nodes are skipped)."""
    for rule_node, src, dst in remaps:
        if rule_node not in (None, node_name) or src.startswith("__"):
            continue
        if expand_topic_name(src, node_name, namespace) == fqn:
            return expand_topic_name(dst, node_name, namespace)
    return fqn
