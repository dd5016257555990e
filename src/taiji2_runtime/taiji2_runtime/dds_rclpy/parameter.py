"""rclpy.parameter.Parameter and the value/type rules of ROS 2 parameters."""

from __future__ import annotations

from enum import IntEnum
from typing import Any

PARAMETER_SEPARATOR_STRING = "."


class Parameter:
    """A named, typed parameter value (rclpy.parameter.Parameter)."""

    class Type(IntEnum):
        """Parameter types (rcl_interfaces/msg/ParameterType)."""

        NOT_SET = 0
        BOOL = 1
        INTEGER = 2
        DOUBLE = 3
        STRING = 4
        BYTE_ARRAY = 5
        BOOL_ARRAY = 6
        INTEGER_ARRAY = 7
        DOUBLE_ARRAY = 8
        STRING_ARRAY = 9

        @classmethod
        def from_parameter_value(cls, value: Any) -> Parameter.Type:
            """The type of a Python value, as rclpy infers it.

            Raises
            ------
            TypeError
                If the value cannot be a parameter value.
            """
            if value is None:
                return cls.NOT_SET
            if isinstance(value, bool):
                return cls.BOOL
            if isinstance(value, int):
                return cls.INTEGER
            if isinstance(value, float):
                return cls.DOUBLE
            if isinstance(value, str):
                return cls.STRING
            if isinstance(value, bytes):
                return cls.BYTE_ARRAY
            if isinstance(value, list | tuple):
                if all(isinstance(v, bytes) for v in value) and value:
                    return cls.BYTE_ARRAY
                if all(isinstance(v, bool) for v in value):
                    return cls.BOOL_ARRAY if value else cls.DOUBLE_ARRAY
                if all(isinstance(v, int) and not isinstance(v, bool) for v in value):
                    return cls.INTEGER_ARRAY
                if all(isinstance(v, float) for v in value):
                    return cls.DOUBLE_ARRAY
                if all(isinstance(v, str) for v in value):
                    return cls.STRING_ARRAY
            if hasattr(value, "tolist"):
                return cls.from_parameter_value(value.tolist())
            raise TypeError(f"the value {value!r} is not a valid parameter value (mixed or unsupported types)")

        def check(self, parameter_value: Any) -> bool:
            """True when ``parameter_value`` is of this type."""
            if self == Parameter.Type.NOT_SET:
                return parameter_value is None
            try:
                actual = Parameter.Type.from_parameter_value(parameter_value)
            except TypeError:
                return False
            if actual == self:
                return True
            # an empty list is a valid value of every array type
            return isinstance(parameter_value, list | tuple) and not parameter_value and self.name.endswith("ARRAY")

    def __init__(self, name: str, type_: Parameter.Type | None = None, value: Any = None) -> None:
        if type_ is None:
            type_ = Parameter.Type.from_parameter_value(value)
        if not isinstance(type_, Parameter.Type):
            raise TypeError("type must be an instance of Parameter.Type")
        if not type_.check(value):
            raise ValueError(f"Type {type_.name} and value {value!r} do not agree")
        self._name = name
        self._type = type_
        self._value = list(value) if isinstance(value, tuple) else value

    @property
    def name(self) -> str:
        return self._name

    @property
    def type_(self) -> Parameter.Type:
        return self._type

    @property
    def value(self) -> Any:
        return self._value

    def __repr__(self) -> str:
        return f"Parameter(name={self._name!r}, type_={self._type.name}, value={self._value!r})"
