"""The rosbags type store of the workspace: ROS 2 Humble types plus this workspace's ``.msg`` files.

Kept apart from :mod:`taiji2_runtime.interfaces` (which builds Cyclone DDS classes) so that
reading bags does not import Cyclone DDS.
"""

from __future__ import annotations

import importlib.resources
import os
from functools import cache
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

__all__ = ["WORKSPACE_INTERFACE_PACKAGES", "contract_typestore", "rihs01", "split_type", "typestore",
           "workspace_msg_definitions"]

#: interface packages of this workspace (their .msg files are the single source of truth)
WORKSPACE_INTERFACE_PACKAGES = ("taiji2_msgs",)


def split_type(msgtype: str) -> tuple[str, str, str]:
    """Split ``pkg/msg/Name`` (or ``pkg/Name``) into its three parts.

    Raises
    ------
    ValueError
        If ``msgtype`` is not a ROS 2 interface type name.
    """
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"not a ROS 2 message type name: {msgtype!r} (expected pkg/msg/Name)")
    return parts[0], parts[1], parts[2]


def _msg_dirs(package: str) -> list[Path]:
    dirs: list[Path] = []
    try:
        resource = importlib.resources.files(f"{package}.msg")
        dirs.append(Path(str(resource)))
    except (ModuleNotFoundError, TypeError):
        pass
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share" / package / "msg")
    return [d for d in dirs if d.is_dir()]


def workspace_msg_definitions(package: str) -> dict[str, str]:
    """``{"pkg/msg/Name": msg_text}`` for every ``.msg`` file of an interface package.

    Raises
    ------
    LookupError
        If no ``.msg`` file of ``package`` can be found.
    """
    for directory in _msg_dirs(package):
        files = sorted(directory.glob("*.msg"))
        if files:
            return {f"{package}/msg/{f.stem}": f.read_text(encoding="utf-8") for f in files}
    raise LookupError(f"no .msg definitions found for interface package {package!r}")


@cache
def typestore() -> Typestore:
    """The rosbags type store holding the standard ROS 2 Humble types and this workspace's messages."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    for package in WORKSPACE_INTERFACE_PACKAGES:
        for msgtype, text in workspace_msg_definitions(package).items():
            store.register(get_types_from_msg(text, msgtype))
    return store


#: the standard ROS 2 types the raw topics use (the same definitions in Humble and Jazzy)
CONTRACT_STANDARD_DEFINITIONS = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Wrench": "Vector3 force\nVector3 torque\n",
    "geometry_msgs/msg/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
}


@cache
def contract_typestore() -> Typestore:
    """A type store with only what the raw topics need: this workspace's messages and the few
    standard types they use (:data:`CONTRACT_STANDARD_DEFINITIONS`).

    For reading raw data: it is built in milliseconds, where :func:`typestore` first creates the
    classes of every Humble type (about 0.1 s, a tenth of an offline calibration). Types a bag
    brings are registered into it from the bag's own definitions, as into :func:`typestore`.
    """
    store = get_typestore(Stores.EMPTY)
    for msgtype, text in CONTRACT_STANDARD_DEFINITIONS.items():
        store.register(get_types_from_msg(text, msgtype))
    for package in WORKSPACE_INTERFACE_PACKAGES:
        for msgtype, text in workspace_msg_definitions(package).items():
            store.register(get_types_from_msg(text, msgtype))
    return store


def _char_as_uint8(desc: tuple) -> tuple:
    """A rosbags field description with ``char`` read as rosidl reads it: ``uint8``."""
    kind, args = desc
    if kind == 1 and args[0] == "char":  # Nodetype.BASE
        return kind, ("uint8", args[1])
    if kind in (3, 4):  # Nodetype.ARRAY, Nodetype.SEQUENCE
        return kind, (_char_as_uint8(args[0]), args[1])
    return desc


@cache
def _hash_typestore() -> Typestore:
    """Type descriptions as rosidl hashes them: Jazzy's definitions (type hashes exist from Jazzy
    on; Humble's differ for a few types) with ``char`` as ``uint8`` (rosidl maps the .msg ``char``
    to IDL ``uint8`` before hashing), plus this workspace's messages."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for package in WORKSPACE_INTERFACE_PACKAGES:
        for msgtype, text in workspace_msg_definitions(package).items():
            store.register(get_types_from_msg(text, msgtype))
    for name, (consts, fields) in list(store.fielddefs.items()):
        store.fielddefs[name] = (consts, [(field, _char_as_uint8(desc)) for field, desc in fields])
    return store


def rosidl_hash_typestore() -> Typestore:
    """Jazzy's definitions and this workspace's as rosidl hashes them (``char`` as ``uint8``)."""
    return _hash_typestore()


@cache
def jazzy_typestore() -> Typestore:
    """Jazzy's standard definitions as written, plus this workspace's messages."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for package in WORKSPACE_INTERFACE_PACKAGES:
        for msgtype, text in workspace_msg_definitions(package).items():
            store.register(get_types_from_msg(text, msgtype))
    return store


def register_for_hashing(definitions: dict) -> None:
    """Add rosbags type definitions (e.g. service request/response bodies) to the hashing store."""
    store = _hash_typestore()
    store.register(definitions)
    for name in definitions:
        consts, fields = store.fielddefs[name]
        store.fielddefs[name] = (consts, [(field, _char_as_uint8(desc)) for field, desc in fields])


@cache
def rihs01(msgtype: str) -> str:
    """REP 2011 type hash (``RIHS01_<64 hex>``) of a ROS 2 type, as rosidl computes it for Jazzy.

    A type only :func:`typestore` knows (registered from a bag's embedded definition) is hashed
    from that definition.

    Raises
    ------
    KeyError
        If neither store knows the type.
    """
    name = "/".join(split_type(msgtype))
    store = _hash_typestore()
    return (store if name in store.fielddefs else typestore()).hash_rihs01(name)
