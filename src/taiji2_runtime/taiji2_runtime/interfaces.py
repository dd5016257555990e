"""ROS 2 message classes for machines without ROS 2, derived from ``.msg`` definitions.

Definitions come from two places and nowhere else:

* the ``.msg`` files of the workspace's interface packages (``taiji2_msgs``), the same files
  that rosidl compiles on a ROS 2 machine, found as package data of ``<pkg>.msg`` or under
  ``share/<pkg>/msg`` of any prefix in ``AMENT_PREFIX_PATH``;
* the standard ROS 2 Humble definitions (std_msgs, geometry_msgs, builtin_interfaces, ...)
  shipped by ``rosbags``.

Each message becomes a Cyclone DDS ``IdlStruct`` dataclass registered under the ROS 2 DDS type
name ``<pkg>::msg::dds_::<Name>_``, so that its serialisation is the XCDR1 little-endian byte
stream rosidl produces, and a real ROS 2 node on rmw_cyclonedds_cpp can read it. Instances
behave like rclpy messages: keyword construction, defaults for every field, constants as class
attributes, ``get_fields_and_field_types()``.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.resources
import threading
import types
from functools import cache
from typing import Any

import cyclonedds.idl.types as idl_types
from cyclonedds.idl import IdlStruct

from taiji2_runtime import fast_cdr
from taiji2_runtime.typestore import (  # noqa: F401  (re-exported: the rosbags side, without Cyclone DDS)
    WORKSPACE_INTERFACE_PACKAGES,
    split_type,
    typestore,
    workspace_msg_definitions,
)

_BASE_TYPES: dict[str, Any] = {
    "bool": bool,
    "byte": idl_types.uint8,
    "char": idl_types.uint8,
    "int8": idl_types.int8,
    "uint8": idl_types.uint8,
    "int16": idl_types.int16,
    "uint16": idl_types.uint16,
    "int32": idl_types.int32,
    "uint32": idl_types.uint32,
    "int64": idl_types.int64,
    "uint64": idl_types.uint64,
    "float32": idl_types.float32,
    "float64": idl_types.float64,
    "string": str,
    "wstring": str,
}
_BASE_DEFAULTS: dict[str, Any] = {"bool": False, "string": "", "wstring": "", "float32": 0.0, "float64": 0.0}
#: Non-zero field defaults of standard messages, which rosbags' stored definitions do not carry
#: (rosidl: geometry_msgs/Quaternion ``float64 w 1``). This workspace's .msg files declare none.
_FIELD_DEFAULTS: dict[str, dict[str, Any]] = {"geometry_msgs/msg/Quaternion": {"w": 1.0}}

# rosbags node kinds (rosbags.typesys.base.Nodetype): BASE=1, NAME=2, ARRAY=3, SEQUENCE=4
_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4

_lock = threading.RLock()


def dds_type_name(msgtype: str) -> str:
    """DDS type name of a ROS 2 message type, e.g. ``geometry_msgs::msg::dds_::WrenchStamped_``."""
    pkg, kind, name = split_type(msgtype)
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_name(dds_name: str) -> str | None:
    """Inverse of :func:`dds_type_name`; None when the DDS type does not follow the ROS 2 convention."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_"):
        return None
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def _field_spec(desc: tuple[int, Any]) -> tuple[Any, Any, str]:
    """(cyclone annotation, default factory, rosidl type string) of a rosbags field description."""
    kind, args = desc
    if kind == _BASE:
        base, bound = args
        annotation = _BASE_TYPES[base]
        if base in ("string", "wstring") and bound:
            annotation = idl_types.bounded_str[bound]
        default = _BASE_DEFAULTS.get(base, 0)
        type_text = f"{base}<={bound}" if bound else base
        return annotation, (lambda d=default: d), type_text
    if kind == _NAME:
        cls = message_class(args)
        pkg, _, name = split_type(args)
        return cls, cls, f"{pkg}/{name}"
    if kind in (_ARRAY, _SEQUENCE):
        sub, size = args
        sub_annotation, sub_default, sub_text = _field_spec(sub)
        if kind == _ARRAY:
            return (
                idl_types.array[sub_annotation, size],
                lambda f=sub_default, n=size: [f() for _ in range(n)],
                f"{sub_text}[{size}]",
            )
        annotation = idl_types.sequence[sub_annotation, size] if size else idl_types.sequence[sub_annotation]
        text = f"sequence<{sub_text}, {size}>" if size else f"sequence<{sub_text}>"
        return annotation, list, text
    raise TypeError(f"unsupported field description {desc!r}")


def _get_fields_and_field_types(cls: type) -> dict[str, str]:
    return dict(cls._ros_field_types)


def _repr(self: Any) -> str:
    body = ", ".join(f"{f}={getattr(self, f)!r}" for f in self._ros_field_types)
    return f"{self._ros_type.replace('/msg/', '.msg.').replace('/', '.')}({body})"


@cache
def type_hash_of(msgtype: str) -> str:
    """REP 2011 type hash (``RIHS01_<64 hex>``) of a ROS 2 message type, as rosidl computes it."""
    from taiji2_runtime.typestore import rihs01

    with _lock:
        return rihs01(msgtype)


def type_hash(msg_type: type) -> str | None:
    """Type hash of a message class of this runtime (None for a class that is not a ROS 2 message)."""
    ros_type = getattr(msg_type, "_ros_type", None)
    return type_hash_of(ros_type) if ros_type else None


@cache
def message_class(msgtype: str) -> type:
    """The message class of a ROS 2 message type name such as ``taiji2_msgs/msg/StarTracker``.

    Raises
    ------
    KeyError
        If the type is unknown to the type store.
    """
    with _lock:
        pkg, kind, name = split_type(msgtype)
        full = f"{pkg}/{kind}/{name}"
        store = typestore()
        if full not in store.fielddefs:
            raise KeyError(f"unknown message type {full!r}")
        consts, fields = store.fielddefs[full]
        field_types: dict[str, str] = {}
        specs = []
        overrides = _FIELD_DEFAULTS.get(full, {})
        for field_name, desc in fields:
            annotation, default_factory, type_text = _field_spec(desc)
            if field_name in overrides:
                default_factory = lambda v=overrides[field_name]: v  # noqa: E731
            specs.append((field_name, annotation, default_factory))
            field_types[field_name] = type_text

        def body(namespace: dict[str, Any]) -> None:
            namespace["__module__"] = f"{pkg}.{kind}"
            namespace["__qualname__"] = name
            for field_name, annotation, default_factory in specs:
                namespace["__annotations__"][field_name] = annotation
                namespace[field_name] = dataclasses.field(default_factory=default_factory)

        # types.new_class runs the IdlMeta.__prepare__ that records the DDS type name
        cls = types.new_class(name, (IdlStruct,), {"typename": dds_type_name(full)}, body)
        cls = dataclasses.dataclass(cls)
        for const_name, _const_type, value in consts:
            setattr(cls, const_name, value)
        cls._ros_type = full
        cls._ros_field_types = field_types
        # plain messages (de)serialise with struct, not Cyclone DDS's interpreted machine (fast_cdr.py)
        codec = fast_cdr.compile_codec(cls, list(fields), message_class,
                                       lambda t: store.fielddefs["/".join(split_type(t))][1])
        if codec is not None:
            fast_cdr.install(cls, codec)
        cls.get_fields_and_field_types = classmethod(_get_fields_and_field_types)
        cls.__repr__ = _repr
        return cls


class _MessageModule:
    """Attribute access ``module.Name`` -> message class of ``<package>/msg/Name``."""

    def __init__(self, package: str) -> None:
        self._package = package

    def __getattr__(self, name: str) -> type:
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return message_class(f"{self._package}/msg/{name}")
        except KeyError as exc:
            raise AttributeError(f"{self._package}.msg has no message {name!r}") from exc

    def __repr__(self) -> str:
        return f"<message module {self._package}.msg (taiji2_runtime)>"


@cache
def message_module(package: str) -> Any:
    """The ``<package>.msg`` namespace of generated classes (no-ROS runtime)."""
    importlib.invalidate_caches()
    return _MessageModule(package)


def message_type_of(msg: Any) -> str:
    """ROS 2 type name (``pkg/msg/Name``) of a message instance or class, for either runtime."""
    cls = msg if isinstance(msg, type) else type(msg)
    ros_type = getattr(cls, "_ros_type", None)
    if ros_type:
        return ros_type
    module = cls.__module__.split(".")
    # rosidl classes live in <pkg>.msg._<snake_name>
    return f"{module[0]}/msg/{cls.__name__}"


def msg_definition(msgtype: str) -> str:
    """Full message definition text (with dependencies, ros2 ``msg`` style) as embedded in bags."""
    text, _encoding = typestore().generate_msgdef(msgtype)
    return text


def to_plain(msg: Any) -> Any:
    """Nested plain Python (dicts, lists, numbers, strings) of a message, for echo and JSON."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: to_plain(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if isinstance(msg, list | tuple):
        return [to_plain(v) for v in msg]
    if hasattr(msg, "tolist"):
        return msg.tolist()
    if isinstance(msg, bytes):
        return list(msg)
    return msg
