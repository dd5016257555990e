"""The ground's uplink plan for time-tagged commanding (ECSS PUS service 11), without middleware (docs/link.md).

* :func:`maneuver_activities`: a maneuver as time-tagged activities, one per change of the torque on
  the command grid (zero-order hold: the torque between activities is the last one released).
* :func:`plan_uplinks`: which pass uplinks which activities: the table of pass k holds the activities
  released from the first instant its uplink can be onboard (pass start + light time + its
  transmission + the onboard time margin) up to that instant of pass k + 1, split into
  TC[11,4]-sized parts; a table over the onboard capacity, or activities no pass can reach in time,
  are refused with a :class:`PlanError` naming them. A table that another follows ends with a zero-torque
  activity where the next one takes over (the spacecraft stops the maneuver if the next table never
  arrives), and the next table re-asserts the torque in effect there.

The onboard side that executes the tables is :class:`taiji2_sim_pkg.core.onboard_schedule.OnboardSchedule`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from taiji2_sim_pkg.core.link import LinkModel

__all__ = ["ACTIVITY_OCTETS", "PlanError", "UplinkTable", "maneuver_activities", "plan_uplinks"]

#: octets one activity takes in a TC[11,4] (release time 8 + torque TC 69)
ACTIVITY_OCTETS = 77


class PlanError(ValueError):
    """A maneuver the link and the onboard schedule cannot carry; the message names why."""


def maneuver_activities(torque_at: Callable[[float], np.ndarray], start_s: float, end_s: float,
                        dt_s: float) -> list[tuple[float, tuple[float, float, float]]]:
    """``(release_s, torque)`` at ``start_s`` and at each grid time in (start, end] where the torque changes."""
    n = round((end_s - start_s) / dt_s)
    out: list[tuple[float, tuple[float, float, float]]] = []
    last = None
    for k in range(n + 1):
        t = start_s + k * dt_s
        torque = tuple(float(v) for v in torque_at(t))
        if torque != last:
            out.append((round(t, 9), torque))
            last = torque
    return out


@dataclass
class UplinkTable:
    """The activities one pass uplinks: sent from ground time ``ready_s`` (the pass start)."""

    contact: int
    ready_s: float
    activities: list[tuple[float, tuple[float, float, float]]] = field(default_factory=list)


def plan_uplinks(activities: list[tuple[float, tuple[float, float, float]]], model: LinkModel,
                 max_passes: int = 10000) -> list[UplinkTable]:
    """Assign ``activities`` (release order) to passes (module docstring).

    Raises
    ------
    PlanError
        Activities released before the first uplink can be onboard, or a pass's table over the capacity.
    """
    if not activities:
        return []
    capacity = model.onboard_schedule_capacity
    transmit_s = 8.0 * (capacity * ACTIVITY_OCTETS) / model.uplink_rate_bps if not math.isinf(
        model.uplink_rate_bps) else 0.0
    if model.contacts.always:
        first = activities[0][0]
        if first < model.light_time_s + transmit_s + model.command_lead_s:
            raise PlanError(f"the first activity at {first:g} s is due before an uplink at t = 0 can be onboard "
                            f"({model.light_time_s + transmit_s + model.command_lead_s:g} s)")
        if len(activities) > capacity:
            raise PlanError(f"{len(activities)} activities, more than the onboard schedule's capacity {capacity}")
        return [UplinkTable(0, 0.0, list(activities))]
    tables: list[UplinkTable] = []
    i = 0
    passes = model.contacts.passes()
    k, start, _end = next(passes)
    earliest = start + model.light_time_s + transmit_s + model.command_lead_s
    if activities[0][0] < earliest:
        late = sum(1 for a in activities if a[0] < earliest)
        raise PlanError(f"{late} activities are due before the first uplink (pass {k} at {start:g} s) can be onboard "
                        f"at {earliest:g} s (light time + uplink of a full table + time margin): start the maneuver "
                        f"at or after {math.ceil(earliest):d} s")
    held: tuple[float, float, float] | None = None
    for _ in range(max_passes):
        if i >= len(activities):
            break
        k1, start1, _end1 = next(passes)
        next_earliest = start1 + model.light_time_s + transmit_s + model.command_lead_s
        table = UplinkTable(k, start)
        if held is not None and activities[i][0] > earliest:
            table.activities.append((earliest, held))  # re-assert the torque in effect (after the safe stop)
        while i < len(activities) and activities[i][0] < next_earliest:
            table.activities.append(activities[i])
            held = activities[i][1]
            i += 1
        if i < len(activities) and held is not None and any(held):
            table.activities.append((next_earliest, (0.0, 0.0, 0.0)))  # safe stop if the next table never comes
        if len(table.activities) > capacity:
            raise PlanError(f"pass {k} must uplink {len(table.activities)} activities (released before the next "
                            f"uplink can be onboard at {next_earliest:g} s), more than the onboard schedule's "
                            f"capacity {capacity}")
        if table.activities:
            tables.append(table)
        k, start, earliest = k1, start1, next_earliest
    return tables
