"""Parameters that mean what they say, identical on rclpy and on the embedded runtime.

A node declares each parameter either *read-only* (read once at start: ``ros2 param set`` is refused, as
rcl refuses any read-only parameter) or *runtime* (``ros2 param set`` takes effect at once). A runtime
parameter has a check, ``value -> problem or None``; :class:`RuntimeParameters` applies it to the value the
node started with (a bad one ends the node with ``error: <node>: <problem>``) and, through a set-parameters
callback, to every later ``set``, refusing a bad value with the same ``<problem>`` text as its reason.

Node code::

    self.declare_parameter("method", "gls", descriptor("...", read_only=True))
    period = self.declare_parameter("publish_period_s", 1.0, descriptor("...")).value
    RuntimeParameters(self, {"publish_period_s": positive("publish_period_s", "s")}, self._apply)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from taiji2_runtime.ros import messages

#: ``value -> problem`` (None when the value is acceptable); the problem names the parameter
Check = Callable[[Any], "str | None"]


def descriptor(description: str, *, read_only: bool = False) -> Any:
    """A ParameterDescriptor; read-only ones say so in their description (``ros2 param describe``)."""
    rcl = messages.rcl_interfaces
    text = f"{description} [read-only: read at start]" if read_only else f"{description} [can be set at run time]"
    return rcl.ParameterDescriptor(description=text, read_only=read_only)


def read_only(description: str) -> Any:
    """The descriptor of a parameter read once at start (``ros2 param set`` refused)."""
    return descriptor(description, read_only=True)


def positive(name: str, unit: str) -> Check:
    """A check that ``name`` is a finite number > 0 [``unit``]."""
    def check(value: Any) -> str | None:
        number = float(value)
        if not number > 0.0 or number == float("inf"):
            return f"{name}: {value!r} is not a finite number > 0 [{unit}]"
        return None
    return check


def within(name: str, low: float, high: float, unit: str) -> Check:
    """A check that ``low <= name <= high`` [``unit``]."""
    def check(value: Any) -> str | None:
        number = float(value)
        if not low <= number <= high:
            return f"{name}: {value!r} is outside [{low}, {high}] [{unit}]"
        return None
    return check


class RuntimeParameters:
    """Validates a node's runtime parameters at start and at every set, and applies accepted values.

    Parameters
    ----------
    node : rclpy Node (either runtime), whose parameters in ``checks`` are already declared.
    checks : name -> check of each runtime parameter.
    apply : called as ``apply(name, value)`` for each accepted new value (all of a set, or none).

    Raises
    ------
    ValueError
        the value a runtime parameter was declared with fails its check (message: the check's problem).
    """

    def __init__(self, node: Any, checks: Mapping[str, Check], apply: Callable[[str, Any], None]) -> None:
        self.checks = dict(checks)
        self.apply = apply
        for name, check in self.checks.items():
            problem = check(node.get_parameter(name).value)
            if problem:
                raise ValueError(problem)
        node.add_on_set_parameters_callback(self.on_set)

    def on_set(self, parameters: list[Any]) -> Any:
        """The set-parameters callback: refuses the whole set with the first problem, else applies it."""
        result = messages.rcl_interfaces.SetParametersResult(successful=True, reason="")
        for parameter in parameters:
            check = self.checks.get(parameter.name)
            problem = check(parameter.value) if check is not None else None
            if problem:
                result.successful, result.reason = False, problem
                return result
        for parameter in parameters:
            if parameter.name in self.checks:
                self.apply(parameter.name, parameter.value)
        return result
