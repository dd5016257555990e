"""command_planner (ground): the maneuver as time-tagged command tables (ECSS PUS TC[11,4]) uplinked in passes.

Turns the maneuver (``maneuver``, as every verb's ``--maneuver``: the layout's shipped design by default,
``paper`` its square wave, or a maneuver file of ``taiji2 design``; ``start_s`` and ``duration_s`` as
maneuver_commander) into activities on the command grid (one per torque change,
:func:`taiji2_ground_pkg.uplink_plan.maneuver_activities`), assigns them to passes of the link
model's contact schedule within the onboard schedule's capacity
(:func:`~taiji2_ground_pkg.uplink_plan.plan_uplinks`; a maneuver that cannot be carried ends the
node with one line naming why), encodes each table as TC[11,4] packets of at most 50 activities and
hands them to the link (``/ground/link/tc``), each stamped with the ground time from which it may be
sent (its pass's start); the plan is latched on ``/ground/commanding/plan`` (JSON). It then follows the
onboard verification reports the ground receives (``/ground/link/reception``): a table without an
acceptance report once a later table's report or the end of the data has come is named "command table
lost on uplink" on ``/diagnostics``, a TM[1,2] "refused at acceptance". Without a usable key file it plans
but sends nothing (the spacecraft would refuse unsigned frames) and says so on ``/diagnostics``.

With ``yamcs_url`` the ground runs on Yamcs: the planner issues the tables, in plan order, as
``insert_activities`` commands of that instance (once its ``ground-station`` link is connected) instead of
sending frames; Yamcs gives each its sequence count and CRC and hands it to the ground station
(:mod:`taiji2_ground_pkg.nodes.yamcs_station`), which signs and uplinks it at its pass; the command
history shows Queued, Released, Sent, then Acceptance and Execution from the onboard reports. The plan is
published again with Yamcs's sequence counts as ``tc_seq`` (what the onboard reports name) once every
table has one; each entry's ``digest`` joins the table as planned and as Yamcs sent it
(:func:`taiji2_ground_pkg.mcs.commanding.table_digest`). No key file is needed here then.
Parameters: ``config/command_planner.yaml``.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Sequence
from typing import Any

from taiji2_ground_pkg.mcs.commanding import stage_counts, table_digest
from taiji2_ground_pkg.uplink_plan import maneuver_activities, plan_uplinks
from taiji2_ground_pkg.uplink_signer import frame_signer
from taiji2_model.maneuver_choice import MANEUVER_HELP, choose_maneuver
from taiji2_runtime import link_topics as lt
from taiji2_runtime.entry import run_node
from taiji2_runtime.node_parameters import read_only
from taiji2_runtime.packets.scheduling import MAX_ACTIVITIES_PER_TC, Activity, encode_insert_activities
from taiji2_runtime.packets.sdls import FrameSigner
from taiji2_runtime.ros import messages, rclpy
from taiji2_sim_pkg.core.link import load_link_model

_NS = 1_000_000_000
PLAN_TOPIC = "/ground/commanding/plan"



class CommandPlanner(rclpy.node.Node):
    """The ground's command planner (module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("command_planner", **node_kwargs)
        dp = self.declare_parameter
        preset = dp("preset", "type1", read_only("layout whose maneuver (design or paper) is flown: type1 | type2")
                    ).value
        asked = dp("maneuver", "", read_only(f"{MANEUVER_HELP}; empty: the default")).value
        start_s = dp("start_s", -1.0, read_only("maneuver start [s] (-1: the preset's or the file's)")).value
        duration_s = dp("duration_s", -1.0, read_only("maneuver duration [s] (-1: the preset's or file's)")).value
        dt_s = 1.0 / dp("command_rate_hz", 10.0, read_only("command grid rate [Hz]")).value
        self.model = load_link_model(dp("link_model", "ideal", read_only(
            "the link model whose passes, light time and onboard schedule the plan follows")).value)
        key_file = dp("key_file", "", read_only("SDLS key file the frames are signed with (docs/security.md)")).value
        spi = dp("spi", -1, read_only("SPI to sign with (-1: the key file's highest active SPI)")).value
        first_sequence = dp("first_sequence", 1, read_only(
            "the first frame's SDLS sequence number (IV counter); above the last the spacecraft accepted")).value
        yamcs_url = str(dp("yamcs_url", "", read_only(
            "issue the tables as commands of this Yamcs instance (yamcs://HOST:PORT/INSTANCE), whose ground "
            "station signs and uplinks them; empty: sign and send them here")).value)
        yamcs_stream = str(dp("yamcs_stream", "tc_realtime", read_only(
            "with yamcs_url: the command stream to issue on: tc_realtime (Yamcs sends packets, the station signs) "
            "or tc_frames (Yamcs signs them as SDLS frames itself)")).value)
        maneuver = choose_maneuver(preset, asked or None, None).maneuver  # ValueError: one line naming the choice
        if start_s >= 0:
            maneuver.start_s = float(start_s)
        if duration_s >= 0:
            maneuver.duration_s = float(duration_s)
        activities = maneuver_activities(maneuver.torque_at, maneuver.start_s,
                                         maneuver.start_s + maneuver.duration_s + dt_s, dt_s)
        tables = plan_uplinks(activities, self.model)  # PlanError (a ValueError) names why it cannot be carried
        self._packets: list[bytes] = []
        self._ready_ns: list[int] = []
        self.plan: list[dict[str, Any]] = []
        seq = request = 0
        for table in tables:
            for j in range(0, len(table.activities), MAX_ACTIVITIES_PER_TC):
                part = table.activities[j:j + MAX_ACTIVITIES_PER_TC]
                self._packets.append(encode_insert_activities(seq, [Activity(round(r * _NS), t) for r, t in part],
                                                              request))
                self._ready_ns.append(round(table.ready_s * _NS))
                self.plan.append({"tc_seq": seq, "pass": table.contact, "ready_s": table.ready_s,
                                  "activities": len(part), "first_release_s": part[0][0],
                                  "last_release_s": part[-1][0], "digest": table_digest(self._packets[-1])})
                seq += 1
                request += len(part)
        self._accepted: set[int] = set()
        self._refused: dict[int, int] = {}
        self._rejected: dict[int, int] = {}
        self._lost: list[int] = []
        self._yamcs = _YamcsCommanding(yamcs_url, yamcs_stream, self._packets, self.plan) if yamcs_url else None
        self.signer, self._key_problem = (None, "") if self._yamcs else self._signer(key_file, spi, first_sequence)
        self._frames = [self.signer.sign(p) for p in self._packets] if self.signer else []
        qos = lt.reliable_all()
        self._tc_pub = self.create_publisher(messages.taiji2_msgs.SpacePackets, lt.GROUND_TC, qos)
        self._plan_pub = self.create_publisher(messages.std_msgs.String, PLAN_TOPIC, lt.latched())
        self._plan_pub.publish(messages.std_msgs.String(data=json.dumps(self.plan)))
        self._diag_pub = self.create_publisher(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(messages.std_msgs.String, lt.RECEPTION_TOPIC, self._on_reception, qos)
        steady = rclpy.clock.Clock(clock_type=rclpy.clock.ClockType.STEADY_TIME)
        self._send_timer = self.create_timer(0.05, self._send, clock=steady)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        self.get_logger().info(f"{len(activities)} activities in {len(tables)} table(s), {len(self._packets)} "
                               f"TC[11,4] packet(s), passes {[t.contact for t in tables]}")

    def _signer(self, key_file: str, spi: int, first_sequence: int) -> tuple[FrameSigner | None, str]:
        """The frame signer, or None and why not (logged)."""
        signer, problem, warning = frame_signer(key_file, spi, first_sequence)
        if problem:
            self.get_logger().error(f"{problem} (the spacecraft refuses frames without a valid MAC)")
        elif warning:
            self.get_logger().warn(warning)
        return signer, problem

    def _send(self) -> None:
        if self._yamcs is not None:
            plan = self._yamcs.plan_with_yamcs_counts()
            if plan is not None:  # every table has Yamcs's count: the plan names them as the reports will
                self.plan = plan
                self._plan_pub.publish(messages.std_msgs.String(data=json.dumps(plan)))
                self._send_timer.cancel()
            return
        if self._tc_pub.get_subscription_count() == 0 or self.signer is None:
            return  # the link is not there yet, or nothing can be signed
        self._tc_pub.publish(lt.burst(self._frames, self._ready_ns, lt.END_NS, end_of_data=True))
        self._send_timer.cancel()

    def _on_reception(self, msg: Any) -> None:
        state = json.loads(msg.data)
        for r in state.get("command_reports", []):
            if r["subtype"] == 1:
                self._accepted.add(r["tc_seq"])
            elif r["subtype"] == 8:
                self._refused[r["tc_seq"]] = r["refused"]
            elif r["subtype"] == 2:
                self._rejected[r["tc_seq"]] = r["failure_code"]
        last = max(self._accepted, default=-1)
        self._lost = [p["tc_seq"] for p in self.plan if p["tc_seq"] not in self._accepted and p["tc_seq"] not in
                      self._rejected
                      and (p["tc_seq"] < last or state.get("end_of_data"))]

    def _publish_diagnostics(self) -> None:
        d = messages.diagnostic_msgs
        problems = [self._key_problem] if self._key_problem else []
        yamcs = self._yamcs.summary() if self._yamcs else {}
        if yamcs.get("problem"):
            problems.append(yamcs["problem"])
        elif yamcs.get("waiting_for_link"):
            problems.append("waiting for Yamcs's ground-station link to issue the tables")
        if yamcs.get("failed"):
            problems.append("failed in Yamcs: " + "; ".join(f"count {f['seq_count']}: {f['message']}"
                                                             for f in yamcs["failed"]))
        if self._rejected:
            problems.append(f"telecommands refused at acceptance (TM[1,2]): #{', #'.join(map(str, self._rejected))}")
        if self._lost:
            problems.append(f"command table lost on uplink: TC[11,4] #{', #'.join(map(str, self._lost))} "
                            "never acknowledged")
        if self._refused:
            problems.append(f"activities refused onboard: {sum(self._refused.values())} (late or over capacity)")
        status = d.DiagnosticStatus(name="command_planner", hardware_id="taiji2_ground",
                                    message="; ".join(problems) or "nominal")
        error = self._key_problem or yamcs.get("problem")
        status.level = (d.DiagnosticStatus.ERROR if error else d.DiagnosticStatus.WARN if problems
                        else d.DiagnosticStatus.OK)
        values = {"tables": len(self.plan), "acknowledged": len(self._accepted), "lost_on_uplink": self._lost,
                  "refused_activities": sum(self._refused.values()), "rejected_at_acceptance": sorted(self._rejected),
                  "spi": self.signer.spi if self.signer else None, "frames": len(self._frames)}
        if yamcs:
            values["yamcs"] = yamcs
        status.values = [d.KeyValue(key=k, value=json.dumps(v)) for k, v in values.items()]
        self._diag_pub.publish(d.DiagnosticArray(status=[status]))


    def destroy_node(self) -> None:
        if self._yamcs is not None:
            self._yamcs.close()
        super().destroy_node()


class _YamcsCommanding:
    """The tables issued to Yamcs from a thread of their own (the node's executor never waits on Yamcs)."""

    def __init__(self, url: str, stream: str, packets: list[bytes], plan: list[dict[str, Any]]) -> None:
        from taiji2_ground_pkg.mcs.commanding import YamcsCommander
        from taiji2_ground_pkg.mcs.yamcs_instance import LINK_NAME

        self._plan = plan
        self._stop = threading.Event()
        self.problem = ""  # why the tables could not be issued (an error)
        self.waiting = True  # until Yamcs's link is connected and the tables are issued (a warning meanwhile)
        self._commander = YamcsCommander(url)  # GroundError (a ValueError) naming a bad address
        comments = [f"table #{p['tc_seq']} of pass {p['pass']}: {p['activities']} activities released "
                    f"{p['first_release_s']:g}-{p['last_release_s']:g} s, uplinked from ground time {p['ready_s']:g} s"
                    for p in plan]

        def issue() -> None:
            try:
                if self._commander.wait_for_link(LINK_NAME, stop=self._stop):
                    self._commander.issue(packets, comments, stream)
            except Exception as exc:  # Yamcs refused or went away: said on /diagnostics, never a crash
                self.problem = f"tables not issued to Yamcs {url}: {type(exc).__name__}: {exc}"
            finally:
                self.waiting = False

        self._thread = threading.Thread(target=issue, name="command-planner-yamcs", daemon=True)
        self._thread.start()

    def plan_with_yamcs_counts(self) -> list[dict[str, Any]] | None:
        """The plan with ``tc_seq`` = Yamcs's sequence count (``table`` the planner's index), once all are known."""
        history = self._commander.history()
        if len(history) < len(self._plan) or any(h["seq_count"] is None for h in history):
            return None
        return [{**p, "table": p["tc_seq"], "tc_seq": int(h["seq_count"])}
                for p, h in zip(self._plan, history, strict=True)]

    def summary(self) -> dict[str, Any]:
        """Tables issued, per stage the count passed, the failed ones with Yamcs's reason, the problem if any."""
        return {**stage_counts(self._commander.history()), "problem": self.problem, "waiting_for_link": self.waiting}

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10.0)
        self._commander.close()


def main(args: Sequence[str] | None = None) -> int:
    return run_node(CommandPlanner, args)


if __name__ == "__main__":
    raise SystemExit(main())
