"""DDS types of ROS 2 service requests and replies, as rmw_cyclonedds_cpp puts them on the wire.

A request travels on ``rq<service>Request`` and its reply on ``rr<service>Reply``, with DDS type
names ``<pkg>::srv::dds_::<Srv>_Request_`` / ``_Response_``. rmw_cyclonedds_cpp prefixes each
sample with a request header of two 64-bit integers: the client's writer instance handle and the
request's sequence number (the service copies both into the reply). In XCDR1 a struct nested after
16 bytes of header is laid out exactly as if its fields followed the header, so the DDS class here
is ``(client_guid: uint64, sequence_number: int64, body: <the message>)``.

The message bodies come from the service definitions below (rosbags ships messages, not
services); the fields they use (rcl_interfaces/msg/...) are ROS 2's own. The type hash in the
endpoints' USER_DATA is REP 2011's for ``<pkg>/srv/<Srv>_Request`` / ``_Response``.
"""

from __future__ import annotations

import dataclasses
import types
from functools import cache
from typing import Any

import cyclonedds.idl.types as idl_types
from cyclonedds.idl import IdlStruct

#: rcl_interfaces' parameter services (Humble and Jazzy define them alike)
SERVICE_DEFINITIONS = {
    "rcl_interfaces/srv/DescribeParameters": ("string[] names", "ParameterDescriptor[] descriptors"),
    "rcl_interfaces/srv/GetParameters": ("string[] names", "ParameterValue[] values"),
    "rcl_interfaces/srv/GetParameterTypes": ("string[] names", "uint8[] types"),
    "rcl_interfaces/srv/ListParameters": (
        "uint64 DEPTH_RECURSIVE=0\nstring[] prefixes\nuint64 depth", "ListParametersResult result"),
    "rcl_interfaces/srv/SetParameters": ("Parameter[] parameters", "SetParametersResult[] results"),
    "rcl_interfaces/srv/SetParametersAtomically": ("Parameter[] parameters", "SetParametersResult result"),
}


def _bodies(srv: str, kind: str) -> dict[str, Any]:
    """rosbags definitions of ``srv``'s request and response bodies, named ``<pkg>/<kind>/<Srv>_<suffix>``."""
    from rosbags.typesys import get_types_from_msg

    pkg, _, name = srv.split("/")
    bodies = {}
    for suffix, text in zip(("Request", "Response"), SERVICE_DEFINITIONS[srv], strict=True):
        # parsed as a message of the package (so bare field types resolve to <pkg>/msg/...),
        # then filed under ``kind`` (rosbags cannot parse a ``srv`` name itself)
        (definition,) = get_types_from_msg(text, f"{pkg}/msg/{name}_{suffix}").values()
        bodies[f"{pkg}/{kind}/{name}_{suffix}"] = definition
    return bodies


@cache
def service_body_class(srv: str, suffix: str) -> type:
    """Message class of a request/response body (registered as ``<pkg>/msg/<Srv>_<suffix>``)."""
    from taiji2_runtime.interfaces import _lock, message_class
    from taiji2_runtime.typestore import typestore

    pkg, _, name = srv.split("/")
    with _lock:
        if f"{pkg}/msg/{name}_{suffix}" not in typestore().fielddefs:
            typestore().register(_bodies(srv, "msg"))
    return message_class(f"{pkg}/msg/{name}_{suffix}")


@cache
def service_type_hash(srv: str, suffix: str) -> str:
    """REP 2011 hash of ``<pkg>/srv/<Srv>_<suffix>`` (as rosidl generates it for Jazzy)."""
    from taiji2_runtime.typestore import register_for_hashing, rihs01

    pkg, _, name = srv.split("/")
    register_for_hashing(_bodies(srv, "srv"))
    return rihs01(f"{pkg}/srv/{name}_{suffix}")


@cache
def wire_class(srv: str, suffix: str) -> type:
    """The DDS class of ``srv``'s request (``suffix='Request'``) or reply (``'Response'``)."""
    body = service_body_class(srv, suffix)
    pkg, _, name = srv.split("/")

    def namespace(ns: dict[str, Any]) -> None:
        ns["__annotations__"].update(client_guid=idl_types.uint64, sequence_number=idl_types.int64, body=body)
        ns["client_guid"] = 0
        ns["sequence_number"] = 0
        ns["body"] = dataclasses.field(default_factory=body)

    cls = types.new_class(f"{name}_{suffix}_", (IdlStruct,), {"typename": f"{pkg}::srv::dds_::{name}_{suffix}_"},
                          namespace)
    return dataclasses.dataclass(cls)
