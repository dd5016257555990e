"""Record, play and inspect ROS 2 bags: ``record``, ``play``, ``info`` (as ros2 bag, without ROS).

``taiji2 bag record [TOPIC ...] [-a] [-o DIR] [-s mcap|sqlite3] [--use-sim-time] [--max-duration S]``
``taiji2 bag play BAG [-r RATE | --fast] [--clock [HZ]] [-l] [--topics T ...] [--remap FROM:=TO ...]``
``taiji2 bag info BAG|PACKETS [--json] [--full]``
``taiji2 bag export BAG --ccsds OUT [--telecommands] [--time-correlation FILE]``
``taiji2 bag import PACKETS -o BAG [-s mcap|sqlite3] [--time-correlation FILE]``
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import signal
import sys
import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

_DRAIN_IDLE_S = 0.3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bag_verb", metavar="<record|play|info|export|import>")
    sub.required = True

    rec = sub.add_parser("record", help="record topics of the live graph into a bag",
                         description="Record topics into a crash-safe ROS 2 bag (MCAP by default). "
                                     "SIGINT/SIGTERM stop cleanly (a second one skips draining the queues).")
    rec.add_argument("topics", nargs="*", help="topics to record (also those that appear later)")
    rec.add_argument("-a", "--all", action="store_true", help="record every topic (hidden ones excluded)")
    rec.add_argument("-e", "--regex", help="also record topics matching this regular expression")
    rec.add_argument("-x", "--exclude", help="do not record topics matching this regular expression")
    rec.add_argument("--include-hidden-topics", action="store_true", help="with -a / -e, include hidden topics")
    rec.add_argument("-o", "--output", help="bag directory to create (default: rosbag2_<date>-<time>)")
    rec.add_argument("-s", "--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage (default mcap)")
    rec.add_argument("--use-sim-time", action="store_true",
                     help="stamp messages with the /clock time instead of the system time")
    rec.add_argument("--max-duration", type=float, metavar="S",
                     help="stop after S seconds (recorder clock) from the first recorded message")
    rec.add_argument("-d", "--max-bag-duration", type=float, default=300.0, metavar="S",
                     help="start a new storage file every S wall seconds (default 300)")
    rec.add_argument("--journal-period", type=float, default=0.5, metavar="S",
                     help="crash safety: at most the last S wall seconds are lost on SIGKILL (default 0.5)")
    rec.add_argument("--custom-data", nargs="+", default=[], metavar="KEY=VALUE",
                     help="store these pairs in the bag's custom data (metadata.yaml), as ros2 bag record does")

    play = sub.add_parser("play", help="publish the messages of a bag",
                          description="Publish a bag's messages, byte for byte, with their original timing "
                                      "(scaled by --rate) or as fast as subscribers take them (--fast).")
    play.add_argument("bag", help="bag directory (or .mcap / .db3 file)")
    speed = play.add_mutually_exclusive_group()
    speed.add_argument("-r", "--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    speed.add_argument("--fast", action="store_true",
                       help="ignore the timing: as fast as subscribers take the messages (lossless)")
    play.add_argument("--topics", nargs="+", metavar="TOPIC", help="play only these topics")
    play.add_argument("--remap", "-m", nargs="+", default=[], metavar="FROM:=TO", help="rename topics")
    play.add_argument("--clock", nargs="?", type=float, const=40.0, default=None, metavar="HZ",
                      help="publish /clock from the bag time at HZ (default 40) of wall time")
    play.add_argument("-l", "--loop", action="store_true", help="start over at the end")
    play.add_argument("--wait-for-subscribers", type=int, default=0, metavar="N",
                      help="start once every played topic has N subscribers")
    play.add_argument("--wait-timeout", type=float, default=30.0, metavar="S",
                      help="give up waiting for subscribers after S seconds (default 30)")
    play.add_argument("--ack-timeout", type=float, default=30.0, metavar="S",
                      help="at the end, wait up to S seconds for subscribers to acknowledge (default 30)")

    info = sub.add_parser("info", help="summary of a bag: duration, topics, counts, rates, gaps, provenance",
                          description="Summary of a bag, or of a CCSDS packet file or directory (recognised by "
                                      "content): counts and defects per APID.")
    info.add_argument("bag", help="bag directory (or .mcap / .db3 file), or a CCSDS packet file or directory")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.add_argument("--full", action="store_true", help="show long custom data values in full")
    info.add_argument("--time-correlation", metavar="FILE", help="packets: onboard -> contract time YAML")

    export = sub.add_parser("export", help="write a bag's raw topics as CCSDS space packets",
                            description="Write the raw-data contract topics of a bag as one file of CCSDS space "
                                        "packets (docs/interfaces.md): one APID per stream, in onboard-time order.")
    export.add_argument("bag", help="bag directory (or .mcap / .db3 file)")
    export.add_argument("--ccsds", required=True, metavar="OUT", help="packet file to write (must not exist)")
    export.add_argument("--telecommands", action="store_true",
                        help="also write each command as a torque PUS telecommand (APID 0x140)")
    export.add_argument("--time-correlation", metavar="FILE", help="contract -> onboard time YAML (default identity)")

    imp = sub.add_parser("import", help="write a contract bag from CCSDS space packets",
                         description="Decode a CCSDS packet file or directory (defects counted per APID) and write "
                                     "the raw-data contract bag.")
    imp.add_argument("packets", help="packet file or directory")
    imp.add_argument("-o", "--output", required=True, help="bag directory to create")
    imp.add_argument("-s", "--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage (default mcap)")
    imp.add_argument("--time-correlation", metavar="FILE", help="onboard -> contract time YAML (default: the "
                                                                "directory's time_correlation.yaml, else identity)")


class _Stop:
    """SIGINT / SIGTERM -> a flag (the first asks for a clean stop, the second for an immediate one)."""

    def __init__(self) -> None:
        self.requested = threading.Event()
        self.hurry = threading.Event()

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)

    def _handle(self, _signum: int, _frame: Any) -> None:
        if self.requested.is_set():
            self.hurry.set()
        self.requested.set()


def _init_rclpy(rclpy: Any, stop: _Stop) -> None:
    try:  # real rclpy: keep its handlers out, ours drain the queues before shutting down
        options = importlib.import_module(f"{rclpy.__name__}.signals").SignalHandlerOptions
    except (ImportError, AttributeError):
        options = None
    if options is not None:
        rclpy.init(args=["taiji2"], signal_handler_options=options.NO)
    else:
        rclpy.init(args=["taiji2"])
    stop.install()  # after init: replaces the handlers the embedded runtime installs


def _pairs(items: list[str]) -> dict[str, str]:
    """``KEY=VALUE`` items as a dict; a bad item is a ValueError naming it."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--custom-data: {item!r} is not KEY=VALUE")
        out[key] = value
    return out


def _record(args: argparse.Namespace) -> int:
    from taiji2_runtime.bag.recorder import Recorder, RecordOptions
    from taiji2_runtime.ros import rclpy

    output = Path(args.output or datetime.now().strftime("rosbag2_%Y_%m_%d-%H_%M_%S"))
    options = RecordOptions(output=output, topics=list(args.topics), all_topics=args.all, regex=args.regex,
                            exclude=args.exclude, include_hidden=args.include_hidden_topics, storage=args.storage,
                            max_duration_s=args.max_duration, segment_period_s=args.max_bag_duration,
                            journal_period_s=args.journal_period, command_line=["taiji2", *sys.argv[1:]],
                            custom_data=_pairs(args.custom_data))
    if not (options.topics or options.all_topics or options.regex):
        raise ValueError("nothing to record: give topics, -a/--all or -e/--regex")
    stop = _Stop()
    _init_rclpy(rclpy, stop)
    node = recorder = None
    try:
        node = rclpy.create_node(f"taiji2_bag_record_{os.getpid()}")
        if args.use_sim_time:
            node.set_parameters([rclpy.parameter.Parameter("use_sim_time", rclpy.parameter.Parameter.Type.BOOL,
                                                           True)])
        executor = rclpy.executors.SingleThreadedExecutor()
        executor.add_node(node)
        recorder = Recorder(node, options)
        print(f"recording into {output} ({args.storage}); Ctrl-C to stop", file=sys.stderr, flush=True)
        while not stop.requested.is_set() and not recorder.stopped and rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
            recorder.tick()
        # drain what the subscriptions already hold (acknowledged to the publishers) before closing
        last_count, idle_since = recorder.message_count, time.monotonic()
        while not stop.hurry.is_set() and rclpy.ok() and time.monotonic() - idle_since < _DRAIN_IDLE_S:
            executor.spin_once(timeout_sec=0.02)
            recorder.tick()
            if recorder.message_count != last_count:
                last_count, idle_since = recorder.message_count, time.monotonic()
        report = recorder.close()
        recorder = None
    finally:
        if recorder is not None:
            recorder.writer.abort()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    total = sum(report.counts.values())
    print(f"recorded {total - report.dropped} messages on {len(report.counts)} topics into {report.path}",
          file=sys.stderr)
    for topic in sorted(report.counts):
        print(f"  {topic} [{report.types[topic]}]: {report.counts[topic]}", file=sys.stderr)
    for topic, reason in sorted(report.skipped.items()):
        print(f"  {topic}: not recorded ({reason})", file=sys.stderr)
    for topic in report.missing:
        print(f"  {topic}: never published", file=sys.stderr)
    if report.dropped:
        print(f"  {report.dropped} messages received but not recorded: bag storage failed ({report.storage_error})",
              file=sys.stderr)
    return 0


def _parse_remaps(items: list[str]) -> dict[str, str]:
    remap = {}
    for item in items:
        if ":=" not in item:
            raise ValueError(f"--remap {item!r}: expected FROM:=TO")
        source, target = item.split(":=", 1)
        if not source or not target:
            raise ValueError(f"--remap {item!r}: expected FROM:=TO")
        remap[source] = target
    return remap


def _play(args: argparse.Namespace) -> int:
    from taiji2_runtime.bag.player import Player, PlayOptions
    from taiji2_runtime.bag.reading import check_bag_path
    from taiji2_runtime.ros import rclpy

    options = PlayOptions(bag=check_bag_path(args.bag), rate=args.rate, fast=args.fast, topics=args.topics,
                          remap=_parse_remaps(args.remap), clock_hz=args.clock, loop=args.loop,
                          wait_for_subscribers=args.wait_for_subscribers, wait_timeout_s=args.wait_timeout,
                          ack_timeout_s=args.ack_timeout)
    if not options.rate > 0:
        raise ValueError(f"--rate must be > 0, got {options.rate:g}")
    stop = _Stop()
    _init_rclpy(rclpy, stop)
    node = None
    try:
        node = rclpy.create_node(f"taiji2_bag_play_{os.getpid()}")
        player = Player(node, options)
        report = player.run(stop=lambda: stop.requested.is_set() or not rclpy.ok())
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    total = sum(report.published.values())
    ratio = f" ({report.bag_span_s / report.playing_s:.0f}x real time)" if report.playing_s > 0 else ""
    print(f"published {total} messages on {len(report.published)} topics: {report.bag_span_s:.1f} s of bag time "
          f"in {report.playing_s:.2f} s{ratio}{f', {report.loops} loops' if report.loops > 1 else ''}"
          f"{f', {report.clock_messages} /clock' if report.clock_messages else ''}; "
          f"acknowledged {report.acked_after_s:.2f} s later", file=sys.stderr)
    for topic in sorted(report.published):
        print(f"  {topic}: {report.published[topic]}", file=sys.stderr)
    for topic, reason in sorted(report.skipped.items()):
        print(f"  {topic}: skipped ({reason})", file=sys.stderr)
    if report.unacknowledged:
        print(f"warning: not every subscriber acknowledged everything on {', '.join(report.unacknowledged)}",
              file=sys.stderr)
    return 0


def _correlation(args: argparse.Namespace) -> Any:
    from taiji2_runtime.packets.time_correlation import load_time_correlation

    return load_time_correlation(args.time_correlation) if args.time_correlation else None


def _info(args: argparse.Namespace) -> int:
    from taiji2_runtime.bag.info import bag_info, format_info, info_json
    from taiji2_runtime.packets.files import is_packet_path

    if is_packet_path(args.bag):
        return _packet_info(args)
    summary = bag_info(args.bag)
    if args.json:
        print(json.dumps(info_json(summary)))
    else:
        print(format_info(summary, full_custom_data=args.full))
    return 0


def _packet_info(args: argparse.Namespace) -> int:
    from taiji2_runtime.packets.files import read_packets

    decoded = read_packets(args.bag, _correlation(args))
    streams = {name: {"apid": f"0x{d.stream.apid:03X}", "topic": d.stream.topic, "samples": len(d),
                      "start_ns": int(d.stamp_ns[0]) if len(d) else None,
                      "end_ns": int(d.stamp_ns[-1]) if len(d) else None}
               for name, d in decoded.streams.items()}
    if decoded.telecommands is not None:
        streams["telecommands"] = {"apid": "0x140", "topic": "(torque telecommands)",
                                   "samples": len(decoded.telecommands)}
    if args.json:
        print(json.dumps({"path": str(args.bag), "format": "ccsds", "time_correlation": decoded.correlation.as_dict(),
                          "streams": streams, "packets": decoded.report.as_dict()}))
        return 0
    print(f"CCSDS packets: {args.bag}")
    print(f"time correlation: contract = {decoded.correlation.offset_s!r} s + {decoded.correlation.rate!r} x onboard")
    for name, info in streams.items():
        span = ""
        if info.get("start_ns") is not None:
            span = f", {info['start_ns'] / 1e9:.6f} .. {info['end_ns'] / 1e9:.6f} s"
        print(f"  {name} [APID {info['apid']}] -> {info['topic']}: {info['samples']} samples{span}")
    print("\n".join(decoded.report.lines()))
    defects = decoded.report.defects()
    print("defects: " + (", ".join(f"{k} {v}" for k, v in defects.items()) if defects else "none"))
    return 0


def _export(args: argparse.Namespace) -> int:
    from taiji2_runtime.packets.bag_io import read_bag_streams
    from taiji2_runtime.packets.bulk_encode import encode_streams
    from taiji2_runtime.packets.files import write_packets

    started = time.perf_counter()
    streams, left_out = read_bag_streams(args.bag)
    octets = encode_streams(streams, _correlation(args), telecommands=args.telecommands)
    write_packets(args.ccsds, octets)
    total = sum(v[0].shape[0] for v in streams.values())
    print(f"wrote {total} packets ({len(octets)} octets) to {args.ccsds} in {time.perf_counter() - started:.2f} s",
          file=sys.stderr)
    for topic, counts in left_out.items():
        if counts:
            print(f"  {topic}: not exported " + ", ".join(f"{k} {v}" for k, v in counts.items()), file=sys.stderr)
    return 0


def _import(args: argparse.Namespace) -> int:
    from taiji2_runtime.packets.bag_io import write_bag
    from taiji2_runtime.packets.files import read_packets

    started = time.perf_counter()
    decoded = read_packets(args.packets, _correlation(args))
    written = write_bag(args.output, decoded, storage=args.storage,
                        custom_data={"taiji2.packets.source": str(args.packets),
                                     "taiji2.packets.time_correlation": json.dumps(decoded.correlation.as_dict()),
                                     "taiji2.packets.report": json.dumps(decoded.report.as_dict())})
    print(f"wrote {sum(written.values())} messages to {args.output} in {time.perf_counter() - started:.2f} s",
          file=sys.stderr)
    for topic, n in written.items():
        print(f"  {topic}: {n}", file=sys.stderr)
    for line in decoded.report.lines():
        print(line, file=sys.stderr)
    return 0


def main(args: argparse.Namespace) -> int:
    return {"record": _record, "play": _play, "info": _info, "export": _export,
            "import": _import}[args.bag_verb](args)
