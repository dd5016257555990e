"""What authenticating the uplink costs: CPU of signing and verifying one TC frame, times the frames of a run,
against that run's CPU time.

Frames of the run's kind (a TC[11,4] of 12 activities: the largest the planner sends) are signed by the ground's
:class:`FrameSigner` and verified by the onboard :class:`FrameVerifier` (AES-256-GCM of ``cryptography``),
``--frames`` of each, after a warm-up; the CPU per frame is the process time over them. Beside it, in the same
run, the baseline: the CPU of building the same frames' packets (TC[11,4] encoding, spacepackets), which the
run pays anyway. The run's numbers come from its own output: ``--run-dir`` is the ``--out`` of a
``taiji2 experiment --link`` run (its ``results.json`` gives the tables the planner signed and the spacecraft
verified) and ``--run-cpu-s`` the CPU time ``benchmarks/bench_link.py`` printed for it.

    python benchmarks/bench_sdls.py --run-dir DIR --run-cpu-s S [--frames 20000]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def cpu_per_call_s(fn, n: int) -> float:
    """Process time of ``fn(k)`` per call over ``k = 0..n-1`` [s], after ``n // 10`` untimed calls."""
    for k in range(n // 10):
        fn(k)
    start = time.process_time()
    for k in range(n):
        fn(k)
    return (time.process_time() - start) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run-dir", required=True, help="the --out of a taiji2 experiment --link run")
    parser.add_argument("--run-cpu-s", type=float, required=True, help="that run's CPU time [s] (bench_link.py)")
    parser.add_argument("--frames", type=int, default=20_000, help="frames signed and verified (default 20000)")
    args = parser.parse_args()
    from taiji2_runtime.packets.scheduling import MAX_ACTIVITIES_PER_TC, Activity, encode_insert_activities
    from taiji2_runtime.packets.sdls import FrameSigner, FrameVerifier
    from taiji2_runtime.packets.sdls_keys import new_key_table

    results = json.loads((Path(args.run_dir) / "results.json").read_text())
    tables = int(results["link"]["commanding"]["tables"])
    keys = new_key_table((1,))
    activities = [Activity((1000 + k) * 10**9, (1e-6 * k, -1e-6, 0.0)) for k in range(MAX_ACTIVITIES_PER_TC)]
    packet = encode_insert_activities(0, activities)
    total = args.frames + args.frames // 10
    signer = FrameSigner(keys)
    frames = [signer.sign(packet) for _ in range(total)]
    encode_s = cpu_per_call_s(lambda k: encode_insert_activities(k, activities), args.frames)
    timed = FrameSigner(keys)
    sign_s = cpu_per_call_s(lambda k: timed.sign(packet), args.frames)
    # verify each frame once, in order (a replayed frame would be refused early, before the MAC)
    verifier = FrameVerifier(keys)
    start = time.process_time()
    for frame in frames:
        verifier.verify(frame)
    verify_s = (time.process_time() - start) / len(frames)
    assert verifier.accepted == len(frames)
    auth_s = tables * (sign_s + verify_s)
    print(f"SDLS authentication of the uplink ({len(packet)}-octet TC[11,4] in a {len(frames[0])}-octet frame, "
          f"AES-256-GCM, {args.frames} frames):")
    print(f"  sign {1e6 * sign_s:.1f} us, verify {1e6 * verify_s:.1f} us of CPU per frame; building the packet "
          f"(the baseline, paid anyway) {1e6 * encode_s:.1f} us: sign + verify = "
          f"{(sign_s + verify_s) / encode_s:.2f}x the packet's encoding")
    print(f"  the run in {args.run_dir}: {tables} frames signed and verified: {auth_s * 1e3:.2f} ms of CPU "
          f"against the run's {args.run_cpu_s:.0f} s: {100 * auth_s / args.run_cpu_s:.2e} % (goal <= 5 %)")


if __name__ == "__main__":
    main()
