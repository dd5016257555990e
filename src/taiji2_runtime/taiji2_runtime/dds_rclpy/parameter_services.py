"""The six rcl_interfaces parameter services of a node (what ``ros2 param`` calls), as rclpy serves them.

``<node>/list_parameters``, ``get_parameters``, ``set_parameters``, ``set_parameters_atomically``,
``describe_parameters`` and ``get_parameter_types``; the answers follow rclpy's
``ParameterService`` (a parameter that is not declared reads as NOT_SET, and setting it fails
with a reason instead of raising in the server).
"""

from __future__ import annotations

from typing import Any

from taiji2_runtime.dds_rclpy.exceptions import ParameterNotDeclaredException
from taiji2_runtime.dds_rclpy.parameter import PARAMETER_SEPARATOR_STRING, Parameter
from taiji2_runtime.dds_rclpy.service import Service
from taiji2_runtime.interfaces import message_class

_T = Parameter.Type
#: ParameterValue field holding each parameter type's value
VALUE_FIELD = {
    _T.BOOL: "bool_value", _T.INTEGER: "integer_value", _T.DOUBLE: "double_value", _T.STRING: "string_value",
    _T.BYTE_ARRAY: "byte_array_value", _T.BOOL_ARRAY: "bool_array_value",
    _T.INTEGER_ARRAY: "integer_array_value", _T.DOUBLE_ARRAY: "double_array_value",
    _T.STRING_ARRAY: "string_array_value",
}


def to_parameter_value(parameter: Parameter) -> Any:
    """rcl_interfaces/msg/ParameterValue of a parameter."""
    msg = message_class("rcl_interfaces/msg/ParameterValue")(type=int(parameter.type_))
    field = VALUE_FIELD.get(parameter.type_)
    if field is not None:
        value = parameter.value
        setattr(msg, field, list(value) if isinstance(value, list | tuple | bytes) else value)
    return msg


def from_parameter_msg(msg: Any) -> Parameter:
    """Parameter of an rcl_interfaces/msg/Parameter (NOT_SET when the type is unknown)."""
    kind = _T(msg.value.type) if msg.value.type in _T._value2member_map_ else _T.NOT_SET
    field = VALUE_FIELD.get(kind)
    value = getattr(msg.value, field) if field else None
    if kind == _T.BYTE_ARRAY:
        value = [bytes([b]) for b in value]
    return Parameter(msg.name, kind, value)


def _result(successful: bool, reason: str = "") -> Any:
    return message_class("rcl_interfaces/msg/SetParametersResult")(successful=successful, reason=reason)


def _list(node: Any, request: Any, response: Any) -> Any:
    """rclpy's listing rule: names without a dot first, dotted names up to ``depth`` levels."""
    names, prefixes = response.result.names, response.result.prefixes
    dotted = []
    for name in node._parameters:
        if PARAMETER_SEPARATOR_STRING in name:
            dotted.append(name)
        elif not request.prefixes or any(name.startswith(p) for p in request.prefixes):
            names.append(name)
    if request.depth == 1:
        return response
    if request.depth != 0:  # DEPTH_RECURSIVE
        dotted = [n for n in dotted if n.count(PARAMETER_SEPARATOR_STRING) < request.depth]
    for name in dotted:
        parent = name.rsplit(PARAMETER_SEPARATOR_STRING, 1)[0]
        wanted = [p for p in request.prefixes if name.startswith(p + PARAMETER_SEPARATOR_STRING)]
        if request.prefixes and not wanted:
            continue
        names.append(name)
        for prefix in [parent, *wanted]:
            if prefix not in prefixes:
                prefixes.append(prefix)
    return response


def _get(node: Any, request: Any, response: Any) -> Any:
    for name in request.names:
        parameter = node._parameters.get(name, Parameter(name))
        response.values.append(to_parameter_value(parameter))
    return response


def _types(node: Any, request: Any, response: Any) -> Any:
    response.types = [int(node._parameters.get(n, Parameter(n)).type_) for n in request.names]
    return response


def _describe(node: Any, request: Any, response: Any) -> Any:
    descriptor_class = message_class("rcl_interfaces/msg/ParameterDescriptor")
    for name in request.names:
        response.descriptors.append(node._descriptors.get(name) or descriptor_class(name=name))
    return response


def _set(node: Any, request: Any, response: Any) -> Any:
    for msg in request.parameters:
        try:
            response.results.append(node.set_parameters([from_parameter_msg(msg)])[0])
        except ParameterNotDeclaredException:
            response.results.append(_result(False, f"parameter '{msg.name}' is not declared"))
        except (TypeError, ValueError) as exc:
            response.results.append(_result(False, str(exc)))
    return response


def _set_atomically(node: Any, request: Any, response: Any) -> Any:
    try:
        response.result = node.set_parameters_atomically([from_parameter_msg(m) for m in request.parameters])
    except ParameterNotDeclaredException as exc:
        response.result = _result(False, f"parameter not declared: {exc}")
    except (TypeError, ValueError) as exc:
        response.result = _result(False, str(exc))
    return response


_SERVICES = {
    "list_parameters": ("rcl_interfaces/srv/ListParameters", _list),
    "get_parameters": ("rcl_interfaces/srv/GetParameters", _get),
    "get_parameter_types": ("rcl_interfaces/srv/GetParameterTypes", _types),
    "describe_parameters": ("rcl_interfaces/srv/DescribeParameters", _describe),
    "set_parameters": ("rcl_interfaces/srv/SetParameters", _set),
    "set_parameters_atomically": ("rcl_interfaces/srv/SetParametersAtomically", _set_atomically),
}


def start_parameter_services(node: Any) -> list[Service]:
    """Create the node's parameter services (``<node fqn>/<service>``)."""
    fqn = node.get_fully_qualified_name()
    return [Service(node.context, srv, f"{fqn}/{name}",
                    lambda request, response, handler=handler: handler(node, request, response))
            for name, (srv, handler) in _SERVICES.items()]
