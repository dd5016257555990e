"""The deep-space link (issue 23): a 24-h Type-1 run through the node graph, and G and d unbiased with link loss.

Three studies:

1. ``graph``: ``taiji2 experiment --link deep_space --duration-s 86400 --record BAG --json`` (one
   pass a day, onboard playback, PUS 11 commanding), its speed against real time (goal >= 100x), and
   the ground's final live estimate against ``taiji2 calibrate BAG`` of the ground recording
   (goal: every G and d within 1e-6 sigma), and the report's requirement times against an independent
   computation: the offline running estimator's first-met data time on the ground bag and the ground time
   the contact schedule gives for it.
2. ``mc``: Monte Carlo through the batch path with the same link model: for each seed a 3-h Type-1
   batch simulation, its star-tracker and GRS packets through :class:`taiji2_sim_pkg.core.link.Downlink`
   (the ``deep_space`` preset: 1 % random + 1 % bursty loss, duplicates, contacts and playback), the
   samples the ground receives calibrated (:func:`taiji2_estimator_pkg.calibration.calibrate`, the bulk
   path of ``taiji2 calibrate``). Goal: mean error / sigma within +-0.3 and error std / sigma in
   [0.85, 1.15] for every G and d (the std's relative standard error over n seeds is 1/sqrt(2(n-1)):
   10 % at 50 seeds).

3. ``yamcs``: the graph run twice back to back, the same seed and maneuver: without a ground on Yamcs, then
   with ``--ground`` (a Yamcs server started here on a fresh data directory; its time to ready reported,
   goal <= 15 s) feeding every received packet to Yamcs and commanding through it. Goals: wall time with
   Yamcs <= 1.25x without; the live estimates of both runs equal (commanding through Yamcs uplinks the
   same frames at the same times); every table passes Acceptance and Execution in Yamcs's command history.

    python benchmarks/bench_link.py [--studies graph,mc,yamcs] [--seeds 50] [--duration-s 10800]
                                    [--graph-duration-s 86400] [--out DIR] [--baseline]
                                    [--maneuver paper] [--override grs.readout_saturation=false]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from taiji2_estimator_pkg.calibration import align_streams, calibrate
from taiji2_estimator_pkg.core.instrument import InstrumentModel
from taiji2_model.config import load_config
from taiji2_sim_pkg.core.link import Downlink, load_link_model
from taiji2_sim_pkg.core.simulator import maneuver_torque_commands, simulate_batch

#: APIDs and packet sizes of the three sensor streams (docs/interfaces.md)
SENSORS = ((0x101, 120), (0x111, 64), (0x112, 64))


def delivered_masks(model, seed: int, n: int, dt_s: float) -> list[np.ndarray]:
    """Which of the n samples of each sensor stream the ground receives (first copies), through the link."""
    link = Downlink(model, seed)
    payload = {apid: bytes(size) for apid, size in SENSORS}
    kept = {apid: np.zeros(n, dtype=bool) for apid, _ in SENSORS}
    out = []
    for k in range(n):
        t = (k + 1) * dt_s
        for apid, _ in SENSORS:
            link.offer(t, apid, payload[apid])
        if k % 1000 == 999:
            out += link.advance(t)
    out += link.advance(n * dt_s) + link.drain()
    for d in out:
        if not d.duplicate:
            kept[d.apid][round(d.generated_s / dt_s) - 1] = True
    return [kept[apid] for apid, _ in SENSORS]


def _z(table: dict, out) -> np.ndarray:
    """(12,) (estimate - truth) / sigma of G (both GRS) then d (both GRS)."""
    g = np.concatenate([table[f"grs{k}"]["scale_factors"] for k in (1, 2)])
    g_sig = np.concatenate([np.sqrt(np.diag(table[f"grs{k}"]["scale_factors_cov"])) for k in (1, 2)])
    d = np.concatenate([table[f"grs{k}"]["com_offset"] for k in (1, 2)])
    d_sig = np.concatenate([np.sqrt(np.diag(table[f"grs{k}"]["com_offset_cov"])) for k in (1, 2)])
    return np.concatenate([(g - out.truth.grs_angular_scale_factors[-1].reshape(-1)) / g_sig,
                           (d - out.truth.com_offset_m[-1].reshape(-1)) / d_sig])


def mc(args: argparse.Namespace) -> None:
    config = load_config("type1", overrides={"maneuver.duration_s": args.duration_s})
    n = round(args.duration_s * config.sample_rate_hz)
    dt = 1.0 / config.sample_rate_hz
    commands = maneuver_torque_commands(config, n)
    instrument = InstrumentModel.from_layout("type1")
    model = load_link_model("deep_space")
    z_g, z_d, lost, z_full = [], [], [], []
    started = time.monotonic()
    for i in range(args.seeds):
        seed = 5000 + i
        out = simulate_batch(config, seed, commands)
        stamps = np.rint(out.t_s * 1e9).astype(np.int64)
        keep_st, keep_1, keep_2 = delivered_masks(model, seed, n, dt)
        lost.append([1 - keep_st.mean(), 1 - keep_1.mean(), 1 - keep_2.mean()])
        record = align_streams(stamps[keep_st], out.st_quat_xyzw[keep_st],
                               {1: (stamps[keep_1], out.voltages_v[keep_1, 0]),
                                2: (stamps[keep_2], out.voltages_v[keep_2, 1])}, instrument.sample_rate_hz)
        if args.baseline:  # the same seed without the link: the paired difference isolates the link's effect
            full = calibrate(align_streams(stamps, out.st_quat_xyzw, {1: (stamps, out.voltages_v[:, 0]),
                                                                      2: (stamps, out.voltages_v[:, 1])},
                                           instrument.sample_rate_hz), instrument).to_dict()
            z_full.append(_z(full, out))
        table = calibrate(record, instrument).to_dict()
        g = np.concatenate([table[f"grs{k}"]["scale_factors"] for k in (1, 2)])
        g_sig = np.concatenate([np.sqrt(np.diag(table[f"grs{k}"]["scale_factors_cov"])) for k in (1, 2)])
        d = np.concatenate([table[f"grs{k}"]["com_offset"] for k in (1, 2)])
        d_sig = np.concatenate([np.sqrt(np.diag(table[f"grs{k}"]["com_offset_cov"])) for k in (1, 2)])
        z_g.append((g - out.truth.grs_angular_scale_factors[-1].reshape(-1)) / g_sig)
        z_d.append((d - out.truth.com_offset_m[-1].reshape(-1)) / d_sig)
        if i % 10 == 9:
            print(f"  {i + 1} seeds ({time.monotonic() - started:.0f} s)", file=sys.stderr)
    z_g, z_d, lost = np.array(z_g), np.array(z_d), np.array(lost)
    print(f"MC: Type-1 {args.duration_s:g} s, {args.seeds} seeds through the deep_space link model "
          f"(samples lost: star tracker {100 * lost[:, 0].mean():.2f} %, GRS1 {100 * lost[:, 1].mean():.2f} %, "
          f"GRS2 {100 * lost[:, 2].mean():.2f} %); {time.monotonic() - started:.0f} s")
    names = [f"GRS{k} {p}" for k in (1, 2) for p in ("G_Pphi", "G_Ptheta", "G_Ppsi")]
    names += [f"GRS{k} d_{a}" for k in (1, 2) for a in "xyz"]
    z = np.hstack([z_g, z_d])
    ok = True
    for j, name in enumerate(names):
        mean, std = z[:, j].mean(), z[:, j].std(ddof=1)
        good = abs(mean) <= 0.3 and 0.85 <= std <= 1.15
        ok &= good
        print(f"  {name:14s} mean err/sigma {mean:+.3f}  std err/sigma {std:.3f}  {'ok' if good else 'MISS'}")
    print(f"  goal (mean within +-0.3, std in [0.85, 1.15]) {'met' if ok else 'NOT met'} for every parameter")
    if z_full:
        zf = np.array(z_full)
        print("  the same seeds without the link (complete records), and the link's paired effect:")
        for j, name in enumerate(names):
            diff = z[:, j] - zf[:, j]
            print(f"  {name:14s} complete: mean {zf[:, j].mean():+.3f} std {zf[:, j].std(ddof=1):.3f};  "
                  f"with link - complete: mean {diff.mean():+.3f} std {diff.std(ddof=1):.3f}")


def fluid_ground_time_s(x_s: float, model, rate_in_bps: float, first_data_s: float = 0.0) -> float:
    """Independent of the event model: the ground time at which every sample generated up to onboard time
    ``x_s`` has been received, from the contact schedule alone (a fluid model: telemetry generated at
    ``rate_in_bps``, real time sent at once in a pass, the memory played back oldest first with the rest of
    the downlink rate). NaN where a pass does not clear its playback (not handled)."""
    lt, spare = model.light_time_s, model.downlink_rate_bps - rate_in_bps
    oldest = first_data_s  # every sample generated before it has been transmitted
    for _, a, b in model.contacts.passes():
        a, b = a - lt, b - lt  # the spacecraft's transmit window
        if b <= oldest:
            continue
        a = max(a, oldest)
        clear = a + (a - oldest) * rate_in_bps / spare  # the playback of [oldest, a) ends
        if x_s < a:
            t = a + (x_s - oldest) * rate_in_bps / spare
            return t + lt if t <= b else float("nan")
        if x_s < b:
            return max(x_s, clear) + lt if clear <= b else float("nan")
        if clear > b:
            return float("nan")
        oldest = b
    return float("nan")


#: a live requirement time may trail the offline one by this much data time [s]: the live estimates come once per
#: publish period (1 s) of their data, and d's with the G received by then, which may lag the GRS data
ONBOARD_TOLERANCE_S = 2.0


def requirement_times_vs_offline(link: dict, bag: Path, model, rate_in_bps: float) -> None:
    """The report's requirement times against an independent computation: the data time at which the offline
    running estimator first meets each requirement on the ground bag (:func:`taiji2_estimator_pkg.first_met.
    first_met_data_times`) and the ground time at which that data time is on the ground by the contact schedule
    alone (:func:`fluid_ground_time_s`)."""
    from taiji2_estimator_pkg.first_met import first_met_data_times
    from taiji2_estimator_pkg.io import load_raw_bag

    instrument = InstrumentModel.from_layout("type1")
    raw = load_raw_bag(bag)
    record = align_streams(raw.star_tracker.stamp_ns, raw.star_tracker.quat_xyzw,
                           {g: (raw.grs(g).stamp_ns, raw.grs(g).voltages_v) for g in (1, 2)},
                           instrument.sample_rate_hz)
    started = time.monotonic()
    offline = {(r["grs"], r["parameter"]): r["onboard_time_s"] for r in first_met_data_times(record, instrument)}
    print(f"  requirement times: the report against the offline first-met data time on the ground bag "
          f"({time.monotonic() - started:.0f} s) and the schedule's ground time for it")
    worst_onboard, worst_ground, agree = 0.0, 0.0, True
    for r in link["requirements"]:
        x, x_off = r["onboard_time_s"], offline[(r["grs"], r["parameter"])]
        fluid = fluid_ground_time_s(x_off, model, rate_in_bps) if x_off is not None else None
        if x is None or x_off is None:
            agree &= x is None and x_off is None
            print(f"    GRS{r['grs']} {r['parameter']:9s} report {x}, offline {x_off}")
            continue
        d_on, d_ground = x - x_off, r["ground_time_s"] - fluid
        worst_onboard, worst_ground = max(worst_onboard, abs(d_on)), max(worst_ground, abs(d_ground))
        agree &= -1e-3 <= d_on <= ONBOARD_TOLERANCE_S
        print(f"    GRS{r['grs']} {r['parameter']:9s} onboard: report {x:9.1f} s, offline {x_off:9.1f} s "
              f"({d_on:+.1f}); ground: report {r['ground_time_s']:9.1f} s (pass {r['pass']}), "
              f"from the schedule {fluid:9.1f} s ({d_ground:+.1f})")
    print(f"  worst |report - offline| {worst_onboard:.1f} s on board, {worst_ground:.1f} s on the ground; "
          f"{'every' if agree else 'NOT every'} onboard time within [0, +{ONBOARD_TOLERANCE_S:g}] s of the offline one")


def baseline(args: argparse.Namespace) -> None:
    """The MC's seeds calibrated complete (no link): the difference of the means is the link's mean effect."""
    config = load_config("type1", overrides={"maneuver.duration_s": args.duration_s})
    n = round(args.duration_s * config.sample_rate_hz)
    commands = maneuver_torque_commands(config, n)
    instrument = InstrumentModel.from_layout("type1")
    z = []
    started = time.monotonic()
    for i in range(args.seeds):
        out = simulate_batch(config, 5000 + i, commands)
        stamps = np.rint(out.t_s * 1e9).astype(np.int64)
        record = align_streams(stamps, out.st_quat_xyzw, {1: (stamps, out.voltages_v[:, 0]),
                                                          2: (stamps, out.voltages_v[:, 1])}, instrument.sample_rate_hz)
        z.append(_z(calibrate(record, instrument).to_dict(), out))
        if i % 10 == 9:
            print(f"  {i + 1} seeds ({time.monotonic() - started:.0f} s)", file=sys.stderr)
    z = np.array(z)
    print(f"baseline: the same {args.seeds} seeds, complete records (no link); {time.monotonic() - started:.0f} s")
    names = [f"GRS{k} {p}" for k in (1, 2) for p in ("G_Pphi", "G_Ptheta", "G_Ppsi")]
    names += [f"GRS{k} d_{a}" for k in (1, 2) for a in "xyz"]
    # a mean of n independent err/sigma has the standard error std / sqrt(n) (1 / sqrt(n) if honest):
    # a mean more than ~3 of them from 0 is a bias of the calibration, not the seeds'
    for j, name in enumerate(names):
        mean, std = z[:, j].mean(), z[:, j].std(ddof=1)
        se = std / np.sqrt(len(z))
        print(f"  {name:14s} mean err/sigma {mean:+.3f} +- {se:.3f} (s.e., {mean / se:+.1f} s.e.)  "
              f"std err/sigma {std:.3f}")
    c = np.corrcoef(z[:, :6].T)
    print("  correlation of the G errors across seeds (GRS1 G_Pphi, G_Ptheta, G_Ppsi, GRS2 ...):")
    print("  " + np.array2string(c, precision=2).replace("\n", "\n  "))
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        np.save(Path(args.out) / "baseline_err_over_sigma.npy", z)


def graph(args: argparse.Namespace) -> None:
    out = Path(args.out or tempfile.mkdtemp(prefix="bench-link-"))
    bag = out / "ground_bag"
    env = dict(os.environ, ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", "74"))
    live, wall, cpu_s = _experiment(args, out / "run", ["--record", str(bag)])
    # CPU time of the experiment and every node it ran (each waited for): with the cores the machine has,
    # the run cannot be faster than cpu / cores, whatever the scheduling
    cores = os.cpu_count() or 1
    link = live["link"]
    print(f"graph: Type-1 {args.graph_duration_s:g} s through deep_space: {wall:.0f} s wall including start-up "
          f"({args.graph_duration_s / wall:.0f}x real time), the run itself {link['wall_s']:.0f} s "
          f"({link['speed_x_real_time']:.0f}x); goal >= 100x")
    print(f"  CPU time of the experiment and its nodes {cpu_s:.0f} s ({1000 * cpu_s / args.graph_duration_s:.1f} ms "
          f"per simulated second): on {cores} cores at best {args.graph_duration_s * cores / cpu_s:.0f}x real time")
    model = load_link_model("deep_space")
    streams = link["streams"]
    octets = {"star_tracker": 120, "grs1": 64, "grs2": 64, "executed_torque": 64}
    rate_in = sum(8 * (octets[k] + model.packet_overhead_octets) * 10 for k in octets if k in streams)
    requirement_times_vs_offline(link, bag, model, rate_in)
    off = subprocess.run([sys.executable, "-m", "taiji2_apps.cli.main", "calibrate", str(bag), "--json"],
                         capture_output=True, text=True, env=env)
    if off.returncode not in (0, 3):
        print(off.stderr[-2000:])
        raise SystemExit("calibrate failed")
    offline = json.loads(off.stdout)
    worst = 0.0
    for k in (1, 2):
        for key, cov in (("scale_factors", "scale_factors_cov"), ("com_offset", "com_offset_cov")):
            a, b = np.array(live[f"grs{k}"][key]), np.array(offline[f"grs{k}"][key])
            sigma = np.sqrt(np.diag(np.array(offline[f"grs{k}"][cov])))
            dev = np.abs(a - b) / sigma
            worst = max(worst, float(np.nanmax(dev)))
            print(f"  GRS{k} {key}: |live - offline| / sigma = {np.array2string(dev, precision=2)}")
    print(f"  live ground estimate vs taiji2 calibrate of the ground bag: worst {worst:.2e} sigma (goal <= 1e-6)")


def _proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a live process (Linux /proc), e.g. the Yamcs JVM, which is no child that
    ``getrusage`` could count."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _experiment(args: argparse.Namespace, out: Path, extra: list[str],
                environ: dict[str, str] | None = None) -> tuple[dict, float, float]:
    """One graph run (no recording; ``environ`` added to the environment); ``(results, wall_s, cpu_s of the
    experiment and its nodes)``."""
    env = dict(os.environ, ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID", "74"), **(environ or {}))
    cmd = [sys.executable, "-m", "taiji2_apps.cli.main", "experiment", "--link", "deep_space", "--layout", "type1",
           "--duration-s", str(args.graph_duration_s), "--out", str(out), "--json", "--timeout-s", "20000", *extra]
    if args.maneuver:
        cmd += ["--maneuver", args.maneuver]
    for override in args.override:
        cmd += ["--override", override]
    started = time.monotonic()
    cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.monotonic() - started
    cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode not in (0, 3):  # 3: the run ended, a requirement not met (the verdict)
        print(proc.stderr[-3000:])
        raise SystemExit(f"experiment failed ({proc.returncode})")
    cpu_s = (cpu_after.ru_utime - cpu_before.ru_utime) + (cpu_after.ru_stime - cpu_before.ru_stime)
    return json.loads(proc.stdout.strip().splitlines()[-1]), wall, cpu_s


def yamcs(args: argparse.Namespace) -> None:
    """Study 3 (module docstring)."""
    from taiji2_ground_pkg.mcs.yamcs_server import YamcsServer

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))
    from support import free_port

    out = Path(args.out or tempfile.mkdtemp(prefix="bench-link-yamcs-"))
    plain, wall_plain, cpu_plain = _experiment(args, out / "without", [])
    server = YamcsServer(out / "yamcs", http_port=free_port(), station_port=free_port())
    server.start()
    try:
        ready_s = server.wait_ready()
        jvm_before = _proc_cpu_s(server.process.pid)
        ground, wall_ground, cpu_ground = _experiment(args, out / "with", [
            "--ground", server.url, "--station-port", str(server.station_port)], server.operator_environ())
        jvm_s = _proc_cpu_s(server.process.pid) - jvm_before
    finally:
        server.stop()
    d = args.graph_duration_s
    print(f"yamcs: Type-1 {d:g} s through deep_space, back to back (seed 1); Yamcs ready in {ready_s:.1f} s "
          "(goal <= 15 s)")
    print(f"  without Yamcs: {wall_plain:.0f} s wall ({d / wall_plain:.0f}x real time), CPU of the experiment and "
          f"its nodes {cpu_plain:.0f} s")
    print(f"  with Yamcs:    {wall_ground:.0f} s wall ({d / wall_ground:.0f}x), CPU {cpu_ground:.0f} s + the Yamcs "
          f"JVM {jvm_s:.0f} s")
    print(f"  wall with / without = {wall_ground / wall_plain:.3f} (goal <= 1.25); CPU with (JVM included) / "
          f"without = {(cpu_ground + jvm_s) / cpu_plain:.3f}")
    worst = 0.0
    for k in (1, 2):
        for key, cov in (("scale_factors", "scale_factors_cov"), ("com_offset", "com_offset_cov")):
            a, b = np.array(ground[f"grs{k}"][key]), np.array(plain[f"grs{k}"][key])
            sigma = np.sqrt(np.diag(np.array(plain[f"grs{k}"][cov])))
            worst = max(worst, float(np.nanmax(np.abs(a - b) / sigma)))
    print(f"  final estimates with vs without Yamcs: worst |difference| / sigma = {worst:.2e} (goal 0: the same frames "
          "uplinked at the same times)")
    y = ground["link"]["yamcs"]
    commands = y.get("commands", {})
    stages = ("Queued", "Released", "Sent", "Acceptance", "Execution")
    tables = ground["link"]["commanding"]["tables"]
    print(f"  packets: the ground received {y['station']['received']}, sent {y['sent']} to Yamcs, its link read "
          f"{y['read_by_yamcs']}")
    print(f"  commands: {tables} table(s) planned, {commands.get('issued')} issued in Yamcs; "
          + ", ".join(f"{s} {commands.get(s)}" for s in stages) + f"; failed {len(commands.get('failed', []))} "
          "(goal: every table passes every stage)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--studies", default="graph,mc", help="graph, mc, baseline, yamcs (comma-separated)")
    parser.add_argument("--seeds", type=int, default=50)
    parser.add_argument("--duration-s", type=float, default=10800.0, help="MC record length [s]")
    parser.add_argument("--graph-duration-s", type=float, default=86400.0)
    parser.add_argument("--out", default="")
    parser.add_argument("--maneuver", default="", help="graph: the experiment's --maneuver (default: its default)")
    parser.add_argument("--override", action="append", default=[],
                        help="graph: a simulator override dotted.key=value (repeatable), e.g. "
                             "grs.readout_saturation=false to compare with code from before the range requirement")
    parser.add_argument("--baseline", action="store_true",
                        help="MC: also calibrate each seed's complete record (the link's paired effect)")
    args = parser.parse_args()
    from taiji2_runtime.threads import limit_blas_threads

    limit_blas_threads()
    studies = args.studies.split(",")
    if "mc" in studies:
        mc(args)
    if "baseline" in studies:
        baseline(args)
    if "graph" in studies:
        graph(args)
    if "yamcs" in studies:
        yamcs(args)


if __name__ == "__main__":
    main()
