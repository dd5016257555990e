"""Parameter handling of rclpy.node.Node: declaration, overrides, type and range checks, callbacks."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from taiji2_runtime.dds_rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterAlreadyDeclaredException,
    ParameterNotDeclaredException,
)
from taiji2_runtime.dds_rclpy.parameter import Parameter
from taiji2_runtime.interfaces import message_class


def _descriptor_class() -> type:
    return message_class("rcl_interfaces/msg/ParameterDescriptor")


def _result(successful: bool, reason: str = "") -> Any:
    result = message_class("rcl_interfaces/msg/SetParametersResult")()
    result.successful, result.reason = successful, reason
    return result


def _range_violation(descriptor: Any, value: Any) -> str | None:
    values = value if isinstance(value, list) else [value]
    for rng, kind in ((descriptor.floating_point_range, "floating point"), (descriptor.integer_range, "integer")):
        for r in rng:
            for v in values:
                if isinstance(v, int | float) and not isinstance(v, bool) and not r.from_value <= v <= r.to_value:
                    return f"{v!r} is outside the {kind} range [{r.from_value}, {r.to_value}]"
    return None


class ParameterMixin:
    """The parameter API of a node; expects ``self._parameter_overrides`` (name -> value)."""

    _parameter_overrides: dict[str, Any]

    def _init_parameters(self, allow_undeclared: bool) -> None:
        self._parameters: dict[str, Parameter] = {}
        self._descriptors: dict[str, Any] = {}
        self._declared_types: dict[str, Parameter.Type] = {}
        self._set_callbacks: list[Callable[[list[Parameter]], Any]] = []
        self._allow_undeclared = allow_undeclared

    def declare_parameter(
        self, name: str, value: Any = None, descriptor: Any = None, ignore_override: bool = False
    ) -> Parameter:
        """Declare ``name`` with a default value (or a Parameter.Type); command-line overrides win.

        Raises
        ------
        ParameterAlreadyDeclaredException, InvalidParameterTypeException, InvalidParameterValueException
        """
        if name in self._parameters:
            raise ParameterAlreadyDeclaredException([name])
        descriptor = descriptor if descriptor is not None else _descriptor_class()()
        declared_type = value if isinstance(value, Parameter.Type) else Parameter.Type.from_parameter_value(value)
        default = None if isinstance(value, Parameter.Type) else value
        effective = default
        if not ignore_override and name in self._parameter_overrides:
            effective = self._parameter_overrides[name]
        parameter = Parameter(name, value=effective)
        if not descriptor.dynamic_typing and declared_type != Parameter.Type.NOT_SET:
            if not declared_type.check(parameter.value):
                raise InvalidParameterTypeException(parameter, declared_type.name)
            parameter = Parameter(name, declared_type, parameter.value)
        descriptor.name = name
        descriptor.type = int(parameter.type_)
        self._check_and_notify([parameter], {name: descriptor})
        self._parameters[name] = parameter
        self._descriptors[name] = descriptor
        self._declared_types[name] = declared_type
        return parameter

    def declare_parameters(
        self, namespace: str, parameters: Sequence[tuple[Any, ...]], ignore_override: bool = False
    ) -> list[Parameter]:
        """Declare several ``(name, value[, descriptor])`` under ``namespace``."""
        declared = []
        for entry in parameters:
            name = f"{namespace}.{entry[0]}" if namespace else entry[0]
            value = entry[1] if len(entry) > 1 else None
            descriptor = entry[2] if len(entry) > 2 else None
            declared.append(self.declare_parameter(name, value, descriptor, ignore_override))
        return declared

    def undeclare_parameter(self, name: str) -> None:
        if name not in self._parameters:
            raise ParameterNotDeclaredException(name)
        for table in (self._parameters, self._descriptors, self._declared_types):
            table.pop(name, None)

    def has_parameter(self, name: str) -> bool:
        return name in self._parameters

    def get_parameter(self, name: str) -> Parameter:
        if name in self._parameters:
            return self._parameters[name]
        if self._allow_undeclared:
            return Parameter(name)
        raise ParameterNotDeclaredException(name)

    def get_parameter_or(self, name: str, alternative_value: Parameter | None = None) -> Parameter:
        return self._parameters.get(name, alternative_value or Parameter(name))

    def get_parameters(self, names: Sequence[str]) -> list[Parameter]:
        return [self.get_parameter(n) for n in names]

    def get_parameters_by_prefix(self, prefix: str) -> dict[str, Parameter]:
        dotted = prefix + "." if prefix else ""
        return {k[len(dotted):]: v for k, v in self._parameters.items() if k.startswith(dotted)}

    def describe_parameter(self, name: str) -> Any:
        if name not in self._descriptors:
            raise ParameterNotDeclaredException(name)
        return self._descriptors[name]

    def add_on_set_parameters_callback(self, callback: Callable[[list[Parameter]], Any]) -> None:
        self._set_callbacks.insert(0, callback)

    def remove_on_set_parameters_callback(self, callback: Callable[[list[Parameter]], Any]) -> None:
        self._set_callbacks.remove(callback)

    def set_parameters(self, parameter_list: Sequence[Parameter]) -> list[Any]:
        """Set each parameter in turn; returns a SetParametersResult per parameter."""
        return [self._set_one(p) for p in parameter_list]

    def set_parameters_atomically(self, parameter_list: Sequence[Parameter]) -> Any:
        for p in parameter_list:
            if p.name not in self._parameters and not self._allow_undeclared:
                raise ParameterNotDeclaredException(p.name)
        try:
            self._check_and_notify(list(parameter_list), self._descriptors)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            return _result(False, str(exc))
        for p in parameter_list:
            self._parameters[p.name] = p
        return _result(True)

    def _set_one(self, parameter: Parameter) -> Any:
        if parameter.name not in self._parameters:
            if not self._allow_undeclared:
                raise ParameterNotDeclaredException(parameter.name)
            self._parameters[parameter.name] = parameter
            return _result(True)
        descriptor = self._descriptors[parameter.name]
        if descriptor.read_only:
            return _result(False, f"Trying to set a read-only parameter: {parameter.name}.")  # rclpy's words
        declared = self._declared_types[parameter.name]
        if not descriptor.dynamic_typing and declared != Parameter.Type.NOT_SET and not declared.check(parameter.value):
            return _result(False, str(InvalidParameterTypeException(parameter, declared.name)))
        violation = _range_violation(descriptor, parameter.value)
        if violation:
            return _result(False, str(InvalidParameterValueException(parameter.name, parameter.value, violation)))
        refusal = self._callbacks_refusal([parameter])
        if refusal is not None:
            return refusal  # as rclpy: the callback's result, its reason as the callback wrote it
        self._parameters[parameter.name] = parameter
        return _result(True)

    def _callbacks_refusal(self, parameters: list[Parameter]) -> Any:
        """The first unsuccessful SetParametersResult of the set-parameters callbacks (None: all accept)."""
        for callback in self._set_callbacks:
            result = callback(parameters)
            if result is not None and not result.successful:
                return result
        return None

    def _check_and_notify(self, parameters: list[Parameter], descriptors: dict[str, Any]) -> None:
        for p in parameters:
            descriptor = descriptors.get(p.name)
            if descriptor is not None:
                violation = _range_violation(descriptor, p.value)
                if violation:
                    raise InvalidParameterValueException(p.name, p.value, violation)
        result = self._callbacks_refusal(parameters)
        if result is not None:
            names = ", ".join(p.name for p in parameters)
            values = ", ".join(repr(p.value) for p in parameters)
            raise InvalidParameterValueException(names, values, result.reason)
