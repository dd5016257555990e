"""Which estimator parameters ``ros2 param set`` may change while the node runs, and their checks.

Every other parameter of the estimators is read once at start and declared read-only
(``config/estimators.yaml`` marks the runtime ones ``[runtime]``).
"""

from __future__ import annotations

from typing import Any

from taiji2_runtime import node_parameters

#: The parameters ``ros2 param set`` may change while an estimator runs (each takes effect at the next epoch or
#: health report), with their checks; every other parameter is read once at start and declared read-only.
RUNTIME_CHECKS: dict[str, node_parameters.Check] = {
    "publish_period_s": node_parameters.positive("publish_period_s", "s"),
    "checkpoint_period_s": node_parameters.positive("checkpoint_period_s", "s"),
    "starved_after_s": node_parameters.positive("starved_after_s", "s"),
    "paper_batch_period_s": node_parameters.positive("paper_batch_period_s", "s"),
    "missing_warn_fraction": node_parameters.within("missing_warn_fraction", 0.0, 1.0, "fraction"),
}


def accept_runtime_parameters(node: Any, values: dict[str, Any]) -> None:
    """Check the runtime parameters' start values (ValueError) and keep ``values`` equal to every accepted set."""
    checks = {name: check for name, check in RUNTIME_CHECKS.items() if name in values}
    node_parameters.RuntimeParameters(node, checks, values.__setitem__)
