"""Parsing of ``--ros-args`` as rcl does it: ``-p``, ``--params-file``, ``-r``, ``--log-level``."""

from __future__ import annotations

import fnmatch
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from taiji2_runtime.dds_rclpy.exceptions import InvalidRosArgumentsException

ROS_ARGS_FLAG = "--ros-args"
#: severities --log-level accepts (rcutils)
_LOG_LEVELS = ("DEBUG", "INFO", "WARN", "WARNING", "ERROR", "FATAL", "UNSET")
_END_FLAG = "--"
_IGNORED_FLAGS_WITH_VALUE = ("-e", "--enclave", "--log-config-file")
_IGNORED_FLAGS = (
    "--enable-rosout-logs",
    "--disable-rosout-logs",
    "--enable-stdout-logs",
    "--disable-stdout-logs",
    "--enable-external-lib-logs",
    "--disable-external-lib-logs",
)


@dataclass
class ParameterOverride:
    """One parameter value from the command line or a params file, for nodes matching ``node``."""

    node: str | None  # None: every node; else a node name or a params-file node pattern
    name: str
    value: Any
    source: str


@dataclass
class RosArguments:
    """What ``--ros-args`` said."""

    overrides: list[ParameterOverride] = field(default_factory=list)
    remaps: list[tuple[str | None, str, str]] = field(default_factory=list)  # (node, from, to)
    log_level: str | None = None
    unparsed: list[str] = field(default_factory=list)


def _numeric(value: Any) -> Any:
    # YAML 1.1 reads "1e-6" as a string; rcl reads it as a double
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    if isinstance(value, list):
        return [_numeric(v) for v in value]
    return value


def parse_parameter_value(text: str) -> Any:
    """Value of ``name:=value`` by YAML rules, as rcl parses it (``1`` int, ``1.0`` double, ``[..]`` array)."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if value is None and text.strip() not in ("", "~", "null"):
        return text
    return _numeric(value)


def _split_assignment(flag: str, text: str) -> tuple[str | None, str, str]:
    if ":=" not in text:
        raise InvalidRosArgumentsException(f"{flag} expects 'name:=value', got {text!r}")
    lhs, rhs = text.split(":=", 1)
    node: str | None = None
    if ":" in lhs:
        node, lhs = lhs.split(":", 1)
    if not lhs:
        raise InvalidRosArgumentsException(f"{flag} expects 'name:=value', got {text!r}")
    return node, lhs, rhs


def _flatten(prefix: str, tree: Any) -> list[tuple[str, Any]]:
    if isinstance(tree, dict):
        out: list[tuple[str, Any]] = []
        for key, value in tree.items():
            out.extend(_flatten(f"{prefix}.{key}" if prefix else str(key), value))
        return out
    return [(prefix, tree)]


def load_params_file(path: str) -> list[ParameterOverride]:
    """Overrides of a ROS 2 params file (``<node>: {ros__parameters: {...}}``).

    Raises
    ------
    InvalidRosArgumentsException
        If the file cannot be read or does not have the ROS 2 layout.
    """
    file = Path(path)
    try:
        tree = yaml.safe_load(file.read_text(encoding="utf-8"))
    except OSError as exc:
        raise InvalidRosArgumentsException(f"--params-file {path}: cannot read ({exc.strerror})") from exc
    except yaml.YAMLError as exc:
        raise InvalidRosArgumentsException(f"--params-file {path}: not valid YAML ({exc})") from exc
    if not isinstance(tree, dict):
        raise InvalidRosArgumentsException(f"--params-file {path}: expected a mapping of node names")
    overrides: list[ParameterOverride] = []
    for node_key, body in tree.items():
        if not isinstance(body, dict) or "ros__parameters" not in body:
            raise InvalidRosArgumentsException(
                f"--params-file {path}: node entry {node_key!r} has no 'ros__parameters' mapping"
            )
        for name, value in _flatten("", body["ros__parameters"] or {}):
            overrides.append(ParameterOverride(str(node_key), name, value, f"params file {path}"))
    return overrides


def parse_ros_args(args: Sequence[str] | None) -> RosArguments:
    """Parse a full argv (program name first) the way rcl_parse_arguments does.

    Raises
    ------
    InvalidRosArgumentsException
        For a malformed or unknown ``--ros-args`` flag.
    """
    result = RosArguments()
    argv = list(args or [])
    i, in_ros = 0, False
    while i < len(argv):
        arg = argv[i]
        if arg == ROS_ARGS_FLAG:
            in_ros = True
        elif in_ros and arg == _END_FLAG:
            in_ros = False
        elif not in_ros:
            result.unparsed.append(arg)
        else:
            nxt = argv[i + 1] if i + 1 < len(argv) else None
            if arg in ("-p", "--param", "-r", "--remap", "--params-file", "--log-level", *_IGNORED_FLAGS_WITH_VALUE):
                if nxt is None or nxt == _END_FLAG:
                    raise InvalidRosArgumentsException(f"--ros-args: {arg} expects a value")
                i += 1
                if arg in ("-p", "--param"):
                    node, name, text = _split_assignment(arg, nxt)
                    result.overrides.append(ParameterOverride(node, name, parse_parameter_value(text), f"{arg} {nxt}"))
                elif arg in ("-r", "--remap"):
                    node, src, dst = _split_assignment(arg, nxt)
                    result.remaps.append((node, src, dst))
                elif arg == "--params-file":
                    result.overrides.extend(load_params_file(nxt))
                elif arg == "--log-level":
                    level = nxt.split(":=")[-1].upper()
                    if level not in _LOG_LEVELS:  # rcutils' severities (WARNING is accepted for WARN)
                        raise InvalidRosArgumentsException(
                            f"--ros-args: --log-level {nxt!r}: not a severity; one of "
                            f"{', '.join(v.lower() for v in _LOG_LEVELS if v != 'WARNING')}")
                    result.log_level = "WARN" if level == "WARNING" else level
            elif arg in _IGNORED_FLAGS:
                pass
            else:
                raise InvalidRosArgumentsException(f"--ros-args: unknown flag {arg!r}")
        i += 1
    return result


def remove_ros_args(args: Sequence[str] | None = None) -> list[str]:
    """rclpy.utilities.remove_ros_args: argv without the ``--ros-args`` sections."""
    return parse_ros_args(args).unparsed


def node_matches(pattern: str | None, node_name: str, namespace: str) -> bool:
    """Does a ``-p node:`` prefix or params-file node key apply to this node?"""
    if pattern is None:
        return True
    fqn = f"{namespace.rstrip('/')}/{node_name}"
    if pattern in (node_name, fqn, "/**", "**"):
        return True
    glob = pattern.replace("/**", "*") if pattern.startswith("/") else "*/" + pattern
    return fnmatch.fnmatchcase(fqn, glob)
