"""The subset of the rclpy API that the Taiji-2 nodes use, implemented over Eclipse Cyclone DDS.

Module layout mirrors rclpy (``node``, ``qos``, ``executors``, ``task``, ``time``, ``duration``,
``clock``, ``parameter``, ``exceptions``, ``logging``, ``utilities``) so that node code written
against rclpy runs unchanged. Wire conventions are those of rmw_cyclonedds_cpp: DDS topic
``rt/<topic>``, type ``<pkg>::msg::dds_::<Name>_``, XCDR1 little-endian, domain ``ROS_DOMAIN_ID``.
Never import this package directly from node code: use :mod:`taiji2_runtime.ros`.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Sequence
from typing import Any

from taiji2_runtime.dds_rclpy import (
    clock,
    duration,
    exceptions,
    executors,
    logging,
    node,
    parameter,
    qos,
    task,
    time,
    utilities,
)
from taiji2_runtime.dds_rclpy.context import Context, get_default_context
from taiji2_runtime.dds_rclpy.logging import get_logger, set_default_level

__all__ = [
    "Context", "clock", "create_node", "duration", "exceptions", "executors", "get_default_context",
    "get_global_executor", "get_logger", "init", "logging", "node", "ok", "parameter", "qos", "shutdown",
    "spin", "spin_once", "spin_until_future_complete", "task", "time", "try_shutdown", "utilities",
]

_global_executor: executors.Executor | None = None
_signal_handlers_installed = False
_initialized_contexts: list[Context] = []


def _on_signal(signum: int, _frame: Any) -> None:
    reason = f"signal {signal.Signals(signum).name}"
    for context in list(_initialized_contexts):
        context.try_shutdown(reason)


def _install_signal_handlers() -> None:
    global _signal_handlers_installed
    if _signal_handlers_installed or threading.current_thread() is not threading.main_thread():
        return
    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    _signal_handlers_installed = True


def init(
    *, args: Sequence[str] | None = None, context: Context | None = None, domain_id: int | None = None,
    signal_handler_options: Any = None,
) -> None:
    """Initialize a context (the default one unless given) from a full argv.

    SIGINT and SIGTERM shut every initialized context down; ``spin`` then raises
    :class:`executors.ExternalShutdownException`.
    """
    ctx = context or get_default_context()
    if not ctx.ok() and ctx.shutdown_reason is not None:
        ctx.__init__()  # a shut-down default context can be initialized again, as in rclpy
    ctx.init(args, domain_id=domain_id)
    if ctx.args.log_level:
        set_default_level(ctx.args.log_level)
    _initialized_contexts.append(ctx)
    _install_signal_handlers()


def ok(*, context: Context | None = None) -> bool:
    return (context or get_default_context()).ok()


def shutdown(*, context: Context | None = None, uninstall_handlers: bool | None = None) -> None:
    global _global_executor
    ctx = context or get_default_context()
    ctx.shutdown()
    if ctx in _initialized_contexts:
        _initialized_contexts.remove(ctx)
    if ctx is get_default_context() and _global_executor is not None:
        _global_executor.shutdown()
        _global_executor = None


def try_shutdown(*, context: Context | None = None, uninstall_handlers: bool | None = None) -> None:
    ctx = context or get_default_context()
    if ctx.ok():
        shutdown(context=ctx)
    elif ctx in _initialized_contexts:
        _initialized_contexts.remove(ctx)


def create_node(node_name: str, **kwargs: Any) -> node.Node:
    return node.Node(node_name, **kwargs)


def get_global_executor() -> executors.Executor:
    global _global_executor
    if _global_executor is None or _global_executor.context is not get_default_context():
        _global_executor = executors.SingleThreadedExecutor()
    return _global_executor


def _executor_for(n: node.Node, executor: executors.Executor | None) -> executors.Executor:
    if executor is not None:
        return executor
    if n.context is get_default_context():
        return get_global_executor()
    return executors.SingleThreadedExecutor(context=n.context)


def spin(node: node.Node, executor: executors.Executor | None = None) -> None:
    ex = _executor_for(node, executor)
    try:
        ex.add_node(node)
        ex.spin()
    finally:
        ex.remove_node(node)


def spin_once(node: node.Node, *, executor: executors.Executor | None = None, timeout_sec: float | None = None) -> None:
    ex = _executor_for(node, executor)
    try:
        ex.add_node(node)
        ex.spin_once(timeout_sec=timeout_sec)
    finally:
        ex.remove_node(node)


def spin_until_future_complete(
    node: node.Node, future: task.Future, executor: executors.Executor | None = None,
    timeout_sec: float | None = None,
) -> None:
    ex = _executor_for(node, executor)
    try:
        ex.add_node(node)
        ex.spin_until_future_complete(future, timeout_sec)
    finally:
        ex.remove_node(node)
