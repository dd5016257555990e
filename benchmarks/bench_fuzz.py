"""The decoders that read bytes from outside, fuzzed: at least 100,000 hypothesis cases per decoder.

The three decoders and properties of test/fuzz_decoders.py (the packet-file reader, the ground's downlink intake,
the onboard uplink intake with SDLS verification and TC acceptance), each with its strategy, seeded
(derandomised), in a process of its own (``--jobs`` at a time). Per decoder: cases run, uncaught exceptions (the
first one stops the decoder and prints the falsifying input), the largest input, the most calls and the most
memory one input cost against its linear budget, the longest wall time of one case (reported, not a pass/fail:
the budget bounds the work), and what the decoder refused, by reason.

    python benchmarks/bench_fuzz.py [--cases 100000] [--decoders packet_file,downlink,uplink] [--jobs 2]
                                    [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "test"))

DECODERS = ("packet_file", "downlink", "uplink")


def _stats() -> dict[str, Any]:
    return {"cases": 0, "max_octets": 0, "max_calls": 0, "max_calls_per_octet": 0.0, "max_peak_bytes": 0,
            "max_case_ms": 0.0, "wall_s": 0.0}


def _note(stats: dict[str, Any], octets: int, budget: Any, case_s: float) -> None:
    stats["cases"] += 1
    stats["max_octets"] = max(stats["max_octets"], octets)
    stats["max_calls"] = max(stats["max_calls"], budget.calls)
    stats["max_calls_per_octet"] = max(stats["max_calls_per_octet"], budget.calls / max(octets, 1))
    stats["max_peak_bytes"] = max(stats["max_peak_bytes"], budget.peak_bytes)
    stats["max_case_ms"] = max(stats["max_case_ms"], 1e3 * case_s)


def run_decoder(name: str, cases: int) -> dict[str, Any]:
    """Fuzz one decoder for ``cases`` hypothesis cases; its statistics (a pure function of its arguments)."""
    os.environ.setdefault("TAIJI2_RUNTIME", "cyclonedds")
    os.environ["ROS_DOMAIN_ID"] = str(150 + DECODERS.index(name))
    from hypothesis import given

    from taiji2_runtime.ros import rclpy

    import fuzz_decoders as fz

    stats = _stats()
    context = node = None
    try:
        if name == "packet_file":
            strategy = fz.telemetry_octets()

            def check(octets: bytes, budget: Any) -> int:
                fz.check_packet_file(octets, budget)
                return len(octets)
        else:
            context = rclpy.context.Context()
            rclpy.init(args=["bench_fuzz"], context=context)
            if name == "downlink":
                from taiji2_ground_pkg.nodes.ground_receiver import GroundReceiver

                node = GroundReceiver(context=context)
                intake = fz.DownlinkIntake(node)
                strategy = fz.downlink_burst()
            else:
                from taiji2_runtime.packets.sdls import FrameSigner
                from taiji2_runtime.packets.sdls_keys import write_key_file
                from taiji2_sim_pkg.nodes.onboard_executor import OnboardExecutor

                keys = fz.uplink_keys()
                key_file = write_key_file(Path(tempfile.mkdtemp(prefix="bench-fuzz-")) / "k.json", keys)
                node = OnboardExecutor(context=context, cli_args=["--ros-args", "-p", f"key_file:={key_file}"])
                intake = fz.UplinkIntake(node)
                signer = FrameSigner(keys, 2)
                genuine = [FrameSigner(keys, 1).sign(fz.table(0)), signer.sign(fz.table(1, 2_100.0))]
                strategy = fz.uplink_burst(signer, genuine)

            def check(burst: tuple[bytes, int], budget: Any) -> int:
                intake.check(*burst, budget)
                return len(burst[0])

        @fz.fuzz_settings(cases)
        @given(strategy)
        def fuzz(case: Any) -> None:
            budget = fz.Budget()
            started = time.perf_counter()
            octets = check(case, budget)
            _note(stats, octets, budget, time.perf_counter() - started)

        started = time.monotonic()
        try:
            fuzz()
            stats["failure"] = None
        except Exception as exc:  # the property that failed, with hypothesis's falsifying example in its notes
            stats["failure"] = f"{type(exc).__name__}: {exc}"[:2000] + "".join(getattr(exc, "__notes__", []))[:2000]
        stats["wall_s"] = time.monotonic() - started
        if name == "uplink":
            v = node.verifier
            stats["refused"] = {k: int(n) for k, n in v.refused.items() if n}
            stats["accepted_frames"] = v.accepted
            stats["failed_acceptance"] = node._invalid
            stats["scheduled_activities"] = node.schedule.inserted
        elif name == "downlink":
            state = node.reception()
            stats["refused"] = {k: int(n) for k, n in state["rejected"].items()}
            stats["received"] = sum(c["received"] for c in state["counts"].values())
            stats["report_packets"] = state["report_packets"]
    finally:
        if node is not None:
            node.destroy_node()
        if context is not None:
            rclpy.try_shutdown(context=context)
    return stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=100_000, help="hypothesis cases per decoder (default 100000)")
    parser.add_argument("--decoders", default=",".join(DECODERS), help="comma-separated: " + ", ".join(DECODERS))
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="decoders fuzzed at once")
    parser.add_argument("--out", default="", help="directory for fuzz.json")
    args = parser.parse_args()
    import hypothesis

    import fuzz_decoders as fz

    names = [n for n in args.decoders.split(",") if n]
    unknown = sorted(set(names) - set(DECODERS))
    if unknown:
        raise SystemExit(f"--decoders: unknown {unknown}; choose from {', '.join(DECODERS)}")
    started = time.monotonic()
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        results = dict(zip(names, pool.map(run_decoder, names, [args.cases] * len(names)), strict=True))
    wall = time.monotonic() - started
    print(f"fuzzing: {args.cases} hypothesis cases per decoder (derandomised), hypothesis {hypothesis.__version__}, "
          f"{wall:.0f} s wall; budget per input {fz.CALLS_FIXED} + {fz.CALLS_PER_OCTET}/octet calls, "
          f"{fz.BYTES_FIXED >> 20} MiB + {fz.BYTES_PER_OCTET} B/octet")
    print(f"{'decoder':<12} {'cases':>7} {'failures':>8} {'max octets':>10} {'max calls':>10} {'calls/octet':>11} "
          f"{'max MiB':>8} {'max case ms':>11} {'cases/s':>8}")
    for name, s in results.items():
        print(f"{name:<12} {s['cases']:>7} {int(s['failure'] is not None):>8} {s['max_octets']:>10} "
              f"{s['max_calls']:>10} {s['max_calls_per_octet']:>11.1f} {s['max_peak_bytes'] / 2**20:>8.2f} "
              f"{s['max_case_ms']:>11.1f} {s['cases'] / max(s['wall_s'], 1e-9):>8.0f}")
    for name, s in results.items():
        extra = {k: v for k, v in s.items() if k not in _stats() and k != "failure"}
        if extra:
            print(f"  {name}: {json.dumps(extra)}")
        if s["failure"]:
            print(f"  {name} FAILED: {s['failure']}")
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / "fuzz.json").write_text(json.dumps(
            {"cases_per_decoder": args.cases, "hypothesis": hypothesis.__version__, "wall_s": wall,
             "decoders": results}, indent=1))
    if any(s["failure"] for s in results.values()) or any(s["cases"] < args.cases for s in results.values()):
        raise SystemExit(1)


if __name__ == "__main__":
    main()
