"""rclpy.exceptions subset, plus the runtime's own errors (all subclass the rclpy-named ones)."""

from __future__ import annotations

from typing import Any


class NotInitializedException(Exception):
    """rclpy.init() has not been called (or the context is shut down)."""

    def __init__(self, *args: Any) -> None:
        super().__init__("rclpy.init() has not been called", *args)


class ParameterException(Exception):
    """Base of the parameter errors."""


class ParameterNotDeclaredException(ParameterException):
    """A parameter was read or set without having been declared."""

    def __init__(self, parameters: Any) -> None:
        super().__init__(f"Invalid access to undeclared parameter(s): {parameters}")


class ParameterAlreadyDeclaredException(ParameterException):
    """A parameter was declared twice."""

    def __init__(self, parameters: Any) -> None:
        super().__init__(f"Parameter(s) already declared: {parameters}")


class InvalidParameterException(ParameterException):
    """A parameter name is not valid."""

    def __init__(self, parameter: Any) -> None:
        super().__init__(f"Invalid parameter name: {parameter}")


class InvalidParameterValueException(ParameterException):
    """A parameter value was refused (out of range, or refused by a callback)."""

    def __init__(self, parameter: Any, value: Any, reason: str) -> None:
        super().__init__(f"Invalid parameter value ({value!r}) for parameter '{parameter}'. Reason: {reason}")


class InvalidParameterTypeException(ParameterException):
    """A parameter value has the wrong type for the declared parameter."""

    def __init__(self, desired_parameter: Any, expected_type: str) -> None:
        super().__init__(
            f"Trying to set parameter '{desired_parameter.name}' to {desired_parameter.value!r} of type "
            f"'{desired_parameter.type_.name}', expecting type '{expected_type}'"
        )


class ROSInterruptException(Exception):
    """The context was shut down while an operation was waiting."""


class NodeNameNonUniqueError(RuntimeError):
    """A node with the same fully qualified name already exists in the graph."""


class DdsUnavailableError(RuntimeError):
    """The DDS domain could not be created (e.g. no usable network interface)."""


class RCLError(RuntimeError):
    """rcl reported an error (as ``rclpy._rclpy_pybind11.RCLError``)."""


class InvalidRosArgumentsException(RCLError):
    """``--ros-args`` could not be parsed (rclpy raises rcl's ``RCLError`` or ``UnknownROSArgsError``, both
    RuntimeErrors, naming the argument)."""
