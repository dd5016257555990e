"""``main()`` of every node, identical on rclpy and on the embedded runtime.

Bad input (malformed ``--ros-args``, wrong parameter type or range, non-physical configuration,
duplicate node name, no usable DDS interface) ends the process with one line on stderr naming the
problem and exit status 2, never a traceback. ``TAIJI2_DEBUG=1`` shows the traceback.
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from taiji2_runtime.ros import RCLError, rclpy

#: exit status for bad input (as argparse uses)
EXIT_BAD_INPUT = 2


def _user_error_types() -> tuple[type[BaseException], ...]:
    names = ("ParameterException", "InvalidParameterTypeException", "InvalidParameterValueException",
             "ParameterNotDeclaredException", "ParameterAlreadyDeclaredException", "InvalidParameterException",
             "DdsUnavailableError", "NodeNameNonUniqueError", "InvalidNodeNameException",
             "InvalidNamespaceException", "InvalidTopicNameException")
    found = [getattr(rclpy.exceptions, n) for n in names if hasattr(rclpy.exceptions, n)]
    return (ValueError, LookupError, OSError, RCLError, *found)


def _shutdown_types() -> tuple[type[BaseException], ...]:
    external = getattr(rclpy.executors, "ExternalShutdownException", None)
    return (KeyboardInterrupt, external) if external else (KeyboardInterrupt,)


def report_error(program: str, exc: BaseException) -> None:
    """Print ``error: <program>: <message>`` (one line) and, with TAIJI2_DEBUG=1, the traceback."""
    message = " ".join(str(exc).split()) or type(exc).__name__
    print(f"error: {program}: {message}", file=sys.stderr)
    if os.environ.get("TAIJI2_DEBUG"):
        traceback.print_exception(exc)


def _stopping(node: Any) -> bool:
    """True once SIGINT/SIGTERM (or the node itself) shut the context down: an entity torn down
    under a callback that was still running is part of a clean stop, not an error."""
    if node is None:
        return False
    try:
        return not node.context.ok()
    except Exception:
        return True


def run_node(make_node: Callable[[], Any], args: Sequence[str] | None = None, program: str | None = None) -> int:
    """Init the client library, build the node, spin until shutdown; return the exit status."""
    argv = list(sys.argv if args is None else args)
    program = program or os.path.basename(argv[0] if argv else "node")
    node = None
    try:
        rclpy.init(args=argv)
        node = make_node()
        rclpy.spin(node)
    except _shutdown_types():
        pass
    except _user_error_types() as exc:
        # rcl's "failed to initialize wait set: the given context is not valid" when SIGINT shut the
        # context down while the executor was building its wait set: a clean stop, not bad input
        if isinstance(exc, RCLError) and _stopping(node):
            return 0
        report_error(program, exc)
        return EXIT_BAD_INPUT
    except Exception as exc:
        if _stopping(node):
            return 0
        report_error(program, exc)
        return 1
    finally:
        if node is not None:
            try:
                node.destroy_node()
            except Exception:
                pass
        rclpy.try_shutdown()
    return 0
