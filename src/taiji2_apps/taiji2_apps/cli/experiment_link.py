"""``taiji2 experiment --link MODEL``: the experiment through the space link (docs/link.md).

Onboard (namespace ``/onboard``): spacecraft_sim on the onboard bus, the onboard command executor (PUS 11), the
telemetry packetizer. Between: space_link. Ground (``/ground``): the command planner, the ground receiver, both
estimators (on the contract topics the receiver publishes) and, with ``--record``, the recorder of
the ground side. Reports per stream what the link did (generated, delivered, lost, duplicated,
reordered, overwritten, latency), what the ground received, the link faults, and for each
requirement the onboard (data) time and the ground time at which the ground first met it.
Runs the graph through :func:`taiji2_apps.runner.run_graph` (as without ``--link``). Imports only the standard
library and the runner (standard library only) at module level (a verb's rule).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from taiji2_apps.cli.exit_status import ExitStatus
from taiji2_apps.runner import Graph, NodeProcess, Progress, run_to_status

_NS = 1_000_000_000
SCALE_FACTOR_NAMES = ("G_Pphi", "G_Ptheta", "G_Ppsi")
AXES = ("x", "y", "z")


def add_link_arguments(parser: argparse.ArgumentParser) -> None:
    """The link options of ``taiji2 experiment``."""
    parser.add_argument("--link", default="",
                        help="run onboard and ground apart, joined by a space link: a preset of "
                             "taiji2_sim_pkg/config/link.yaml (ideal | deep_space) or a link YAML file (docs/link.md)")
    parser.add_argument("--link-seed", type=int, default=None, help="seed of the link's loss draws (default: --seed)")
    parser.add_argument("--link-fault", action="append", default=[],
                        help="a link fault: missed_contact:K (pass K missed entirely) or lost_uplink:K "
                             "(repeatable; K = 0 is the first pass)")
    parser.add_argument("--key-file", default="",
                        help="SDLS key file (docs/security.md) the planner signs the uplink with and the spacecraft "
                             "checks it against (its highest active SPI signs); default: a throwaway key made for "
                             "this run in a private temporary directory, removed at the end")
    parser.add_argument("--uplink-attack", default="", metavar="KINDS",
                        help="an intruder on the uplink during the run (testing command security, docs/security.md): "
                             "all, or comma-separated forged, replay, bit_flip, revoked, garbage; the results say "
                             "what it sent and what the spacecraft refused")
    parser.add_argument("--ground", default="", metavar="URL",
                        help="the ground station on Yamcs: the Yamcs instance (yamcs://HOST:PORT/INSTANCE, started "
                             "with taiji2 ground serve) that archives every packet the ground receives "
                             "(docs/operations.md); default: none")
    parser.add_argument("--station-port", type=int, default=10015, metavar="PORT",
                        help="with --ground: the port the instance's ground-station link connects to "
                             "(taiji2 ground serve --station-port; default 10015)")
    parser.add_argument("--frame-port", type=int, default=-1, metavar="PORT",
                        help="with --ground on a Yamcs that signs its own SDLS frames (ground serve --sdls-key-file, "
                             "then give the same --key-file here): the UDP port they come to (default the station "
                             "port + 1, as ground serve)")


def estimate_stamps_ns(msg: Any) -> tuple[int, int]:
    """(data, scale factors) stamps [ns] of an estimate message: for a ComOffsetEstimate the time of its last GRS
    sample and the stamp of the G it used (``scale_factors_stamp``); for a ScaleFactorEstimate its stamp twice.
    The estimate rests on data up to the later of the two."""
    data_ns = msg.header.stamp.sec * _NS + msg.header.stamp.nanosec
    g = getattr(msg, "scale_factors_stamp", None)
    return data_ns, data_ns if g is None else g.sec * _NS + g.nanosec


#: wall time [s] between the monitor's checks of the nodes and of the end of the run
MONITOR_PERIOD_S = 0.1
#: after the simulator has finished, wall time without anything moving on the ground (estimates, reception
#: records, the link's report) before the run is declared stuck [s] (as without --link)
STALL_S = 60.0


def spin_for(executor: Any, seconds: float, taken: Callable[[], int]) -> None:
    """Wait ``seconds`` of wall time, then run the callbacks of what arrived meanwhile, until one more spin takes
    nothing (``taken()``: the monitor's count of messages taken).

    The monitor's readers keep all (diagnostics: 100 deep, ~10 a wall second), so nothing is lost while it
    waits, and it takes each reader's queue in batches: spun continuously it woke, and looked at every reader,
    for nearly every message (a 24-h run brings it ~10^6; that cost ~6 % of the run's CPU). The checks after it
    (the nodes' exit status, the end, progress) run about ten times a second."""
    time.sleep(seconds)
    while True:
        before = taken()
        executor.spin_once(timeout_sec=0.0)
        if taken() == before:
            return


class LinkMonitor:
    """Estimate history, truth, the ground receiver's reception log, the link report, diagnostics."""

    def __init__(self, node: Any) -> None:
        from taiji2_runtime.ros import messages, rclpy

        t = messages.taiji2_msgs
        keep_all = rclpy.qos.QoSProfile(history=rclpy.qos.HistoryPolicy.KEEP_ALL,
                                        reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        latched = rclpy.qos.QoSProfile(depth=1, durability=rclpy.qos.DurabilityPolicy.TRANSIENT_LOCAL,
                                       reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        # the truth (1 Hz of data per topic) only for the final report: its latest sample
        latest_only = rclpy.qos.QoSProfile(depth=1, reliability=rclpy.qos.ReliabilityPolicy.RELIABLE)
        self.latest: dict[str, Any] = {}
        self.history: dict[str, list[tuple[int, list[float], list[float]]]] = {}
        #: messages taken so far (spin_for drains the queues until a spin takes none)
        self.taken = 0
        for grs in (1, 2):
            for kind, cls in (("scale_factors", t.ScaleFactorEstimate), ("com_offset", t.ComOffsetEstimate)):
                self._watch(node, cls, f"/taiji2/estimates/grs{grs}/{kind}", keep_all, record=True)
                self._watch(node, cls, f"/taiji2/sim/grs{grs}/{kind}", latest_only)
        self._watch(node, t.ComOffsetEstimate, "/taiji2/estimates/com_offset_difference", keep_all)
        self.reception: list[dict[str, Any]] = []
        self.link_report: dict[str, Any] | None = None
        self.intruder: dict[str, Any] | None = None
        self.station: dict[str, Any] | None = None
        self.diagnostics: dict[str, Any] = {}
        self.faults_seen: dict[str, str] = {}
        s = messages.std_msgs.String
        node.create_subscription(s, "/ground/link/reception", self._counted(
            lambda m: self.reception.append(json.loads(m.data))), keep_all)
        node.create_subscription(s, "/taiji2/sim/link_report", self._counted(self._on_report), latched)
        node.create_subscription(s, "/taiji2/sim/intruder_report", self._counted(
            lambda m: setattr(self, "intruder", json.loads(m.data))), latched)
        node.create_subscription(s, "/ground/yamcs_station", self._counted(
            lambda m: setattr(self, "station", json.loads(m.data))), latched)
        self.plan: list[dict[str, Any]] | None = None
        node.create_subscription(s, "/ground/commanding/plan", self._counted(
            lambda m: setattr(self, "plan", json.loads(m.data))), latched)
        node.create_subscription(messages.diagnostic_msgs.DiagnosticArray, "/diagnostics",
                                 self._counted(self._on_diag), 100)

    def _counted(self, callback: Callable[[Any], None]) -> Callable[[Any], None]:
        """``callback``, counting the messages taken (:attr:`taken`)."""
        def on(msg: Any) -> None:
            self.taken += 1
            callback(msg)

        return on

    def _watch(self, node: Any, cls: type, topic: str, qos: Any, record: bool = False) -> None:
        def on(msg: Any) -> None:
            self.latest[topic] = msg
            if record:
                value = list(msg.scale_factors) if hasattr(msg, "scale_factors") else [msg.offset.x, msg.offset.y,
                                                                                        msg.offset.z]
                sigma = [max(float(msg.covariance[4 * k]), 0.0) ** 0.5 for k in range(3)]
                self.history.setdefault(topic, []).append((max(estimate_stamps_ns(msg)), value, sigma))

        node.create_subscription(cls, topic, self._counted(on), qos)

    def _on_report(self, msg: Any) -> None:
        self.link_report = json.loads(msg.data)

    def _on_diag(self, msg: Any) -> None:
        for status in msg.status:
            self.diagnostics[status.name] = status
            if status.name == "space_link" and status.level > 0:
                for part in status.message.split("; "):
                    name, _, text = part.partition(": ")
                    self.faults_seen[name] = text

    def scale_factors_determined(self) -> bool:
        """The latest scale factors of both GRS are finite (the data determined them: the scale-factor estimator
        publishes NaN until then, and the c.m.-offset estimator waits for finite ones)."""
        import math

        messages = [self.latest.get(f"/taiji2/estimates/grs{g}/scale_factors") for g in (1, 2)]
        return all(m is not None and all(map(math.isfinite, (*m.scale_factors, *m.covariance))) for m in messages)

    def stamps_ns(self, topic: str) -> tuple[int, int]:
        """:func:`estimate_stamps_ns` of the latest estimate on ``topic`` ((-1, -1): none yet)."""
        msg = self.latest.get(topic)
        return (-1, -1) if msg is None else estimate_stamps_ns(msg)


def requirement_times(history: dict[str, list[tuple[int, list[float], list[float]]]],
                      reception: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """For each requirement (G to 0.3 % and d to 100 um, 1 sigma, per GRS and axis): the data (onboard) time
    of the first estimate that met it and the ground time at which the ground had released the data
    through that time (None: not met)."""
    from taiji2_estimator_pkg.report import COM_OFFSET_REQUIREMENT_M, SCALE_FACTOR_REQUIREMENT_REL

    streams = {"scale_factors": ("star_tracker", "grs1", "grs2"), "com_offset": ("grs1", "grs2")}
    out = []
    for grs in (1, 2):
        for kind, names in (("scale_factors", SCALE_FACTOR_NAMES), ("com_offset", AXES)):
            topic = f"/taiji2/estimates/grs{grs}/{kind}"
            for k, name in enumerate(names):
                data_ns = None
                for stamp, value, sigma in history.get(topic, []):
                    bound = (SCALE_FACTOR_REQUIREMENT_REL * abs(value[k]) if kind == "scale_factors"
                             else COM_OFFSET_REQUIREMENT_M)
                    if sigma[k] == sigma[k] and sigma[k] <= bound:
                        data_ns = stamp
                        break
                ground_s = None
                if data_ns is not None:
                    for rec in reception:
                        through = [rec["released_through_s"].get(s) for s in streams[kind]]
                        if rec.get("end_of_data") or all(x is not None and x * _NS >= data_ns - 1000 for x in through):
                            ground_s = rec["ground_time_s"]
                            break
                out.append({"grs": grs, "parameter": name if kind == "scale_factors" else f"d_{name}",
                            "requirement": "0.3 %" if kind == "scale_factors" else "100 um",
                            "onboard_time_s": None if data_ns is None else data_ns / _NS, "ground_time_s": ground_s})
    return out


def earliest_maneuver_start_s(model: Any) -> float:
    """The first time a command table uplinked in the first pass can be executed, rounded up to 10 s."""
    import math

    if model.contacts.always and model.light_time_s == 0 and math.isinf(model.uplink_rate_bps):
        return 0.0
    first = next(model.contacts.passes())[1] if not model.contacts.always else 0.0
    transmit = 0.0 if math.isinf(model.uplink_rate_bps) else 8.0 * 77 * model.onboard_schedule_capacity / \
        model.uplink_rate_bps
    return float(math.ceil((max(first, 0.0) + model.light_time_s + transmit + model.command_lead_s) / 10.0) * 10.0)


def commanding_summary(plan: list[dict[str, Any]] | None, reports: list[dict[str, Any]]) -> dict[str, Any]:
    """Tables planned, acknowledged onboard (TM[1,1]), completed (TM[1,7]), refused activities (TM[1,8]) and
    tables never acknowledged (lost on the uplink), from the plan and the reports the ground received."""
    accepted = {r["tc_seq"]: r for r in reports if r["subtype"] == 1}
    failed = {r["tc_seq"]: r for r in reports if r["subtype"] == 8}
    tables = plan or []
    return {"tables": len(tables), "activities": sum(t["activities"] for t in tables),
            "acknowledged": len(accepted), "completed": sum(1 for r in reports if r["subtype"] == 7),
            "refused_activities": sum(r["refused"] for r in failed.values()),
            "refused_late_tables": sorted(k for k, r in failed.items() if r["failure_code"] == 1),
            "lost_on_uplink": sorted(t["tc_seq"] for t in tables if t["tc_seq"] not in accepted),
            "first_ack_ground_s": min((r["ground_s"] for r in accepted.values()), default=None),
            # tables with an acceptance (TM[1,1|2]) and an execution (TM[1,7|8]) report received: what a command
            # history built from these reports can show (a report the downlink lost leaves its stage pending)
            "reported": {stage: len({r["tc_seq"] for r in reports if r["subtype"] in subtypes})
                         for stage, subtypes in (("Acceptance", (1, 2)), ("Execution", (7, 8)))}}


def pass_of(ground_time_s: float | None, model: Any) -> int | None:
    """Index of the pass a ground time falls in (or the last one before it)."""
    if ground_time_s is None or model.contacts.always:
        return None
    last = None
    for k, start, _ in model.contacts.passes():
        if start > ground_time_s:
            break
        last = k
    return last


#: the verdict's classes of a requirement not met, in the words of the link report
_NOT_MET_WHY = {"cannot": "the Cramer-Rao bound is beyond it", "estimator": "the 1-sigma is beyond it"}


def format_link_report(link: dict[str, Any]) -> str:
    """The per-stream and operations part of the report, as text."""
    lines = [f"link {link['model']['name']} (seed {link['seed']}): light time {link['model']['light_time_s']:g} s, "
             f"contacts {json.dumps(link['model']['contacts'])}, downlink {link['model']['downlink_rate_bps']} bit/s"]
    lines.append(f"  {'stream':16} {'generated':>9} {'delivered':>9} {'lost':>6} {'dupl.':>6} {'reord.':>7} "
                 f"{'overwr.':>7} {'latency med/max [s]':>20} {'missing (ground)':>16}")
    for name, s in link["streams"].items():
        ground = link["ground"].get(name, {})
        med = "-" if s["latency_median_s"] is None else f"{s['latency_median_s']:.1f}"
        mx = "-" if s["latency_max_s"] is None else f"{s['latency_max_s']:.1f}"
        lines.append(f"  {name:16} {s['generated']:9d} {s['delivered']:9d} {s['lost']:6d} {s['duplicated']:6d} "
                     f"{s['reordered']:7d} {s['overwritten']:7d} {med + ' / ' + mx:>20} "
                     f"{ground.get('missing', 0):16d}")
    lines.append("Requirements (the verdict below): met or not at the end; when the 1-sigma first came within the "
                 "requirement: data (onboard) time -> ground time")
    for r in link["requirements"]:
        status = r.get("status", "met")
        head = f"  GRS{r['grs']} {r['parameter']:9} ({r['requirement']}): {'met' if status == 'met' else 'NOT MET'}"
        head += "" if status == "met" else f" ({_NOT_MET_WHY.get(status, status)})"
        if r["onboard_time_s"] is None:
            lines.append(f"{head}; 1-sigma never within")
            continue
        where = "" if r["pass"] is None else f" (pass {r['pass']})"
        lines.append(f"{head}; 1-sigma within from onboard {r['onboard_time_s']:.1f} s -> ground "
                     f"{r['ground_time_s']:.1f} s{where}")
    c = link.get("commanding")
    if c:
        lines.append(f"Commanding (PUS 11): {c['tables']} TC[11,4] with {c['activities']} activities; acknowledged "
                     f"{c['acknowledged']}, completed {c['completed']}, activities refused onboard "
                     f"{c['refused_activities']}, lost on uplink {len(c['lost_on_uplink'])}")
    if link.get("attacks"):
        from taiji2_apps.cli.experiment_attack import format_attacks

        lines.append(format_attacks(link["attacks"]))
    if link.get("yamcs"):
        from taiji2_apps.cli.experiment_ground import format_ground

        lines.append(format_ground(link["yamcs"]))
    faults = link["faults"]
    lines.append("Link faults: " + ("; ".join(f"{k}: {v}" for k, v in faults.items()) if faults else "none"))
    return "\n".join(lines)


def link_key_file(given: str, revoked_spare: bool = False) -> tuple[str, Any]:
    """The key file of the run: ``given`` (checked to load), else a throwaway one (one random SPI-1 key; with
    ``revoked_spare``, SPI 1 revoked and SPI 2 active) in a new private temporary directory, never the repository
    or ``--out``; with the callable that removes it.

    Raises
    ------
    ValueError
        ``given`` is not a usable key file (the message names why, never a key).
    """
    import shutil
    import tempfile

    from taiji2_runtime.packets.sdls_keys import load_key_file, new_key_table, write_key_file

    if given:
        load_key_file(given).newest_active()  # KeyFileError (a ValueError) or no active SPI
        return str(Path(given).resolve()), lambda: None
    folder = tempfile.mkdtemp(prefix="taiji2-keys-")  # mode 0700
    table = new_key_table((1, 2), revoked=(1,)) if revoked_spare else new_key_table((1,))
    path = write_key_file(Path(folder) / "sdls_keys.json", table)
    return str(path), lambda: shutil.rmtree(folder, ignore_errors=True)


def run_link_experiment(args: argparse.Namespace, plan: Any, temporary: bool) -> int:
    """``taiji2 experiment --link``: the whole run (see the module docstring); ``plan`` is the checked experiment
    (:func:`taiji2_apps.experiment_setup.plan_experiment`), ``temporary``: ``args.out`` is removed at the end."""
    import tempfile

    from taiji2_runtime.ros import rclpy
    from taiji2_sim_pkg.core.link import LinkError, load_link_model

    try:
        model = load_link_model(args.link)
        missed, lost_up = [], []
        for fault in args.link_fault:
            kind, _, k = fault.partition(":")
            if kind not in ("missed_contact", "lost_uplink") or not k.isdigit():
                raise LinkError(f"--link-fault {fault!r}: expected missed_contact:K or lost_uplink:K")
            (missed if kind == "missed_contact" else lost_up).append(int(k))
        model = model.with_faults(missed, lost_up)
    except LinkError as exc:
        print(f"error: taiji2 experiment: {exc}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    link_seed = args.seed if args.link_seed is None else args.link_seed
    out = Path(args.out or tempfile.mkdtemp(prefix="taiji2-experiment-"))
    out.mkdir(parents=True, exist_ok=True)
    duration_s = 10800.0 if args.duration_s is None else float(args.duration_s)
    overrides = [f"maneuver.duration_s={duration_s}", *args.override]
    source = ["-p", f"config_file:={args.config}"] if args.config else ["-p", f"layout:={args.layout}"]
    onboard_remaps = []
    for topic in ("/taiji2/star_tracker", "/taiji2/grs1/voltages", "/taiji2/grs2/voltages", "/taiji2/maneuver/command"):
        onboard_remaps += ["-r", f"{topic}:=/onboard{topic}"]
    est_args = ["--ros-args", "-r", "__ns:=/ground", "-p", f"layout:={args.config or args.layout}",
                "-p", f"method:={args.method}"]
    # the plan's resolved choice (experiment.py): a maneuver file, or paper
    commander_maneuver = [f"maneuver:={args.maneuver}"]
    start_s = earliest_maneuver_start_s(model)
    if start_s > 0:
        print(f"experiment: the maneuver starts at {start_s:g} s, when the first command table can be onboard "
              f"(pass start + light time + uplink of a full table + time margin)", file=sys.stderr)
    if start_s >= duration_s:
        print(f"error: taiji2 experiment: --duration-s {duration_s:g} ends before the first command table can be "
              f"onboard ({start_s:g} s)", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    from taiji2_apps.cli.experiment_attack import attack_kinds, leaked_key_file
    from taiji2_apps.cli.experiment_ground import ground_problem, link_count, yamcs_signs_frames

    problem = ground_problem(args.ground, args.station_port) if args.ground else None
    if problem:
        print(f"error: taiji2 experiment: {problem}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    # the link's count and the time before the run: what Yamcs read, and the commands issued, during it
    yamcs_before = (link_count(args.ground), dt.datetime.now(dt.timezone.utc)) if args.ground else (0, None)
    yamcs_frames, problem = yamcs_signs_frames(args) if args.ground else (None, "")
    if problem:
        print(f"error: taiji2 experiment: {problem}", file=sys.stderr)
        return ExitStatus.BAD_INPUT

    try:
        attacks = attack_kinds(args.uplink_attack) if args.uplink_attack else []
    except ValueError as exc:
        print(f"error: taiji2 experiment: {exc}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    try:
        key_file, remove_key = link_key_file(args.key_file, revoked_spare="revoked" in attacks)
    except ValueError as exc:
        print(f"error: taiji2 experiment: --key-file: {exc}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    leaked, remove_leaked = "", lambda: None
    if "revoked" in attacks:
        try:
            leaked, remove_leaked = leaked_key_file(key_file)
        except ValueError as exc:
            remove_key()
            print(f"error: taiji2 experiment: --uplink-attack revoked: {exc}", file=sys.stderr)
            return ExitStatus.BAD_INPUT
    # every relay holds its output until the readers of this graph have matched it (nodes/subscribed_publisher.py):
    # star tracker (scale factors; the paper's d too), GRS (both estimators), executed torque, reception (this
    # monitor, the planner); the recorder reads every ground topic. The uplink's readers onboard: the executor,
    # and the intruder when there is one; counting only one, the link would open as soon as the intruder had
    # matched, and the executor, joining later, would miss the first bursts (the tables and the uplink's
    # horizon) and never command: the simulator, waiting for commands, would crawl
    rec = int(bool(args.record))
    uplink_readers = 1 + bool(attacks)
    # what the ground station receives: the receiver, the recorder's not (it records the ground topics after
    # the receiver), and the Yamcs station when there is one
    downlink_readers = 1 + rec + bool(args.ground)
    receiver_readers = [1 + (args.method == "paper") + rec, 2 + rec, 2 + rec, rec, 2 + rec]
    commands = {
        "scale_factor_estimator": ["run", "taiji2_estimator_pkg", "scale_factor_estimator", *est_args],
        "com_offset_estimator": ["run", "taiji2_estimator_pkg", "com_offset_estimator", *est_args],
        "ground_receiver": ["run", "taiji2_ground_pkg", "ground_receiver", "--ros-args", "-r", "__ns:=/ground",
                            "-p", f"wait_for_subscribers:={receiver_readers}"],
        "space_link": ["run", "taiji2_sim_pkg", "space_link", "--ros-args", "-p", f"model:={args.link}",
                       "-p", f"seed:={link_seed}", "-p", f"missed_contacts:={[*missed, -1]}",
                       "-p", f"lost_uplinks:={[*lost_up, -1]}",
                       "-p", f"wait_for_subscribers:={[downlink_readers, uplink_readers]}"],
        "telemetry_packetizer": ["run", "taiji2_sim_pkg", "telemetry_packetizer", "--ros-args", "-r",
                                 "__ns:=/onboard", "-p", f"end_of_data_s:={duration_s}",
                                 "-p", "command_reports:=true", "-p", "wait_for_subscribers:=[1]"],
        "onboard_executor": ["run", "taiji2_sim_pkg", "onboard_executor", "--ros-args", "-r", "__ns:=/onboard",
                             "-p", "use_sim_time:=true", "-p", "lookahead_s:=10.0",
                             "-p", f"schedule_capacity:={model.onboard_schedule_capacity}",
                             "-p", f"time_margin_s:={model.command_lead_s}", "-p", f"key_file:={key_file}"],
        "command_planner": ["run", "taiji2_ground_pkg", "command_planner", "--ros-args", "-r", "__ns:=/ground",
                            "-p", f"preset:={args.layout}", "-p", f"link_model:={args.link}",
                            "-p", f"start_s:={start_s}", "-p", f"duration_s:={duration_s - start_s}",
                            # on Yamcs the planner issues commands and the station signs them
                            "-p", f"yamcs_url:={args.ground}" if args.ground else f"key_file:={key_file}",
                            "-p", f"yamcs_stream:={yamcs_frames.stream if yamcs_frames else 'tc_realtime'}",
                            *[a for p in commander_maneuver for a in ("-p", p)]],
    }
    # the simulator exits (0) at the end of its data; every other node runs until stopped (what ends the run is
    # the ground's: done(), below)
    if attacks:
        commands["uplink_intruder"] = ["run", "taiji2_sim_pkg", "uplink_intruder", "--ros-args",
                                       "-p", f"attacks:={attacks}", "-p", f"leaked_key_file:={leaked}",
                                       "-p", f"seed:={args.seed}"]
    if args.ground:
        commands["yamcs_station"] = ["run", "taiji2_ground_pkg", "yamcs_station", "--ros-args", "-r", "__ns:=/ground",
                                     "-p", f"station_port:={args.station_port}", "-p", f"yamcs_url:={args.ground}",
                                     "-p", f"key_file:={key_file}",
                                     "-p", f"frame_port:={yamcs_frames.port if yamcs_frames else 0}"]
    nodes = [NodeProcess.taiji2(name, argv) for name, argv in commands.items()]
    nodes.append(NodeProcess.taiji2("spacecraft_sim", [
        "run", "taiji2_sim_pkg", "spacecraft_sim", "--ros-args", "-r", "__ns:=/onboard", *onboard_remaps, *source,
        "-p", f"seed:={args.seed}", "-p", f"duration_s:={duration_s}", "-p", "wait_for_subscribers:=[1, 1, 1]",
        "-p", f"maneuver:={args.maneuver}",
        "-p", "publish_truth_kinematics:=false", "-p", "config_overrides:=" + json.dumps(overrides)], ends=True))
    if args.record:
        # the ground sees no simulator provenance (onboard): it stores what it commanded, under the key a
        # recording's readers take the flown maneuver from (bag/provenance.py)
        nodes.append(NodeProcess.taiji2("recorder", [
            "bag", "record", "-a", "-x", "^/(onboard|taiji2/sim)/", "-o", args.record,
            "--custom-data", f"taiji2.sim.maneuver={plan.maneuver_label}"], stop_last=True))
    rclpy.init(args=["taiji2-experiment"])
    node = rclpy.create_node("taiji2_experiment_link")
    monitor = LinkMonitor(node)
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    sf_topics = [f"/taiji2/estimates/grs{g}/scale_factors" for g in (1, 2)]
    d_topics = [f"/taiji2/estimates/grs{g}/com_offset" for g in (1, 2)]

    def done() -> bool:
        """The ground has received the end of the data, the link's report is in, and the last estimates rest on
        all the data the ground released: d on the last GRS data *and* the last G."""
        final = monitor.reception[-1] if monitor.reception and monitor.reception[-1]["end_of_data"] else None
        if final is None or monitor.link_report is None:
            return False
        through = final["released_through_s"]
        sf_target = max((v for k, v in through.items() if k != "executed_torque" and v is not None), default=0)
        d_target = max((through.get(k) or 0 for k in ("grs1", "grs2")), default=0)
        if not all(monitor.stamps_ns(t)[0] >= sf_target * _NS - 1000 for t in sf_topics):
            return False
        if args.ground and not (monitor.station and monitor.station["end_of_data"] and monitor.station["queued"] == 0):
            return False  # the Yamcs station still has packets to hand over
        if not monitor.scale_factors_determined() and all(monitor.latest.get(t) is None for t in d_topics):
            return True  # G undetermined on all the data (e.g. no maneuver flown): no d can come; the verdict says
        return all(data >= d_target * _NS - 1000 and g >= sf_target * _NS - 1000
                   for data, g in map(monitor.stamps_ns, d_topics))

    def progress() -> Progress:
        stamps = tuple(map(monitor.stamps_ns, sf_topics + d_topics))
        last = monitor.reception[-1] if monitor.reception else {}
        onboard = max((v for v in last.get("released_through_s", {}).values() if v), default=0.0)
        ground = last.get("ground_time_s") or 0.0
        return Progress(max(0, min(min(s) for s in stamps)) / _NS, duration_s,
                        f"ground released data through {onboard:.0f} s at ground time {ground:.0f} s",
                        (stamps, len(monitor.reception), monitor.link_report is not None))

    def stalled(stall_s: float, now: Progress) -> str:
        return (f"the simulator finished {duration_s:g} s, but nothing has moved on the ground for {stall_s:g} s "
                f"({now.summary().strip()}; see the ground node logs in {out})")

    graph = Graph(nodes, out, done=done, progress=progress,
                  wait=lambda s: spin_for(executor, s, lambda: monitor.taken), timeout_s=args.timeout_s,
                  poll_s=MONITOR_PERIOD_S, stall_s=STALL_S, stall_message=stalled, end_grace_s=STALL_S)
    print(f"experiment: {args.config or args.layout}, {plan.maneuver_label}, {duration_s:g} s simulated, "
          f"seed {args.seed}, link {model.name} (seed {link_seed}); node logs in {out}", file=sys.stderr)

    def cleanup() -> None:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        remove_key()
        remove_leaked()

    return run_to_status(graph, lambda result: _report(args, plan, model, link_seed, monitor, out, duration_s,
                                                       result.wall_s, temporary, yamcs_before), cleanup)


def _report(args: argparse.Namespace, plan: Any, model: Any, link_seed: int, monitor: LinkMonitor, out: Path,
            duration_s: float, elapsed: float, temporary: bool, yamcs_before: tuple[int, Any] = (0, None)) -> int:
    """Print the final estimates, the link report and the verdict, write results.json; returns 0 (every
    requirement met) or 3. The estimate table, the requirement section and the verdict are one evaluation
    (:func:`~taiji2_apps.experiment_setup.experiment_verdict`), as in the direct run. ``yamcs_before``:
    the Yamcs link's packet count and the UTC time before the run (with ``--ground``)."""
    from taiji2_apps.experiment_setup import experiment_verdict
    from taiji2_estimator_pkg.report import EstimateTable, format_table

    final = next(rec for rec in reversed(monitor.reception) if rec["end_of_data"])
    table = EstimateTable.from_messages(monitor.latest, layout=args.layout)
    commanding = commanding_summary(monitor.plan, [r for rec in monitor.reception
                                                   for r in rec.get("command_reports", [])])
    # activities refused onboard (late, or over capacity) or tables lost: the spacecraft held other torques than
    # the plan's, whose bound then says nothing of this run (the estimates' 1-sigma still does)
    not_as_planned = ", ".join(part for part in (
        f"{commanding['refused_activities']} activities refused onboard" if commanding["refused_activities"] else "",
        f"{len(commanding['lost_on_uplink'])} command tables lost" if commanding["lost_on_uplink"] else "") if part)
    verdict = experiment_verdict(plan, table, args.layout, monitor.diagnostics, not_as_planned)
    status_of = {c.name: c.status for c in verdict.checks}
    results = table.to_dict()
    requirements = requirement_times(monitor.history, monitor.reception)
    for r in requirements:
        r["pass"] = pass_of(r["ground_time_s"], model)
        r["status"] = status_of.get(f"grs{r['grs']}.{r['parameter']}", "met")
    report = monitor.link_report
    faults = dict(report.get("faults", {}))
    faults.update({k: v for k, v in monitor.faults_seen.items() if k not in faults})
    link = {"model": report["model"], "seed": link_seed, "streams": report["streams"],
            "ground": final["counts"], "requirements": requirements, "faults": faults,
            "contacts_used": report["contacts_used"], "never_transmitted": report["never_transmitted"],
            "memory_peak_octets": report["memory_peak_octets"], "uplink": report["uplink"],
            "final_ground_time_s": final["ground_time_s"], "wall_s": elapsed,
            "speed_x_real_time": duration_s / elapsed}
    link["commanding"] = commanding
    link["frame_security"] = final.get("frame_security")  # the last frame security report the ground received
    if args.uplink_attack:
        from taiji2_apps.cli.experiment_attack import attack_summary

        link["attacks"] = attack_summary(monitor.intruder, monitor.diagnostics)
    if args.ground:
        from taiji2_apps.cli.experiment_ground import ground_summary

        link["yamcs"] = ground_summary(args.ground, monitor.station, *yamcs_before, commanding["reported"])
    if link["commanding"]["lost_on_uplink"]:
        faults["command table lost on uplink"] = ("TC[11,4] #" + ", #".join(
            map(str, link["commanding"]["lost_on_uplink"])) + " never acknowledged")
    # what the link did to the run belongs to the verdict, beside the requirements it leaves unmet
    verdict.warnings.extend(f"link fault: {name}: {text}" for name, text in faults.items())
    if args.ground:
        from taiji2_apps.cli.experiment_ground import publish_verdict

        link["yamcs"]["verdict_parameters"] = publish_verdict(args.ground, *verdict.requirement_counts())
    results["maneuver"] = plan.provenance()
    results["link"] = link
    results["verdict"] = verdict.to_dict()
    (out / "results.json").write_text(json.dumps(results, indent=2))
    if args.json:
        print(json.dumps(results))
    else:
        print(format_table(table))
        print(format_link_report(link))
        kept = (f"results in {out / 'results.json'}" if not temporary or args.keep
                else "--out DIR keeps the node logs and results.json")
        print(f"\n{duration_s:g} s simulated in {elapsed:.1f} s wall ({duration_s / elapsed:.0f}x real time); {kept}\n")
        print("\n".join(verdict.lines()))
    return ExitStatus.OK if verdict.all_met else ExitStatus.NOT_MET

