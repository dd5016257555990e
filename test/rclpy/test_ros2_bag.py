"""Bags both ways with real rosbag2: ``ros2 bag record`` of the real-rclpy graph is calibrated by
``taiji2 calibrate``, and the bag ``taiji2 bag record`` wrote of the same run is read by ``ros2 bag
info`` and played by ``ros2 bag play``.

One 600-s Type-1 experiment (seed 5) per storage: ``spacecraft_sim`` and ``maneuver_commander``
under ``ros2 run``, recorded at once by rosbag2 (the storage under test) and by this project's
recorder (embedded runtime, MCAP). The simulator starts only once both recorders subscribe to every
raw topic.
"""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

RAW_TOPICS = ("/taiji2/star_tracker", "/taiji2/grs1/voltages", "/taiji2/grs2/voltages", "/taiji2/maneuver/command")
SAMPLES = 6000  # 600 s at 10 Hz
#: the QoS override file the README gives rosbag2 (issue 26 row 5): lossless record and play
QOS_OVERRIDES = "$(ros2 pkg prefix taiji2_runtime)/share/taiji2_runtime/config/rosbag2_qos_overrides.yaml"
#: true values of the Type-1 preset (src/taiji2_model/config/type1.yaml)
TRUE_G = {"grs1": [5.524e-8, 5.524e-8, 7.365e-8], "grs2": [5.524e-8, 5.524e-8, 7.365e-8]}
TRUE_D = {"grs1": [1.0e-4, 0.18, 2.0e-4], "grs2": [1.0e-4, -0.18, 2.0e-4]}
#: a fixed seed makes the data deterministic; 4 sigma per component leaves room for any seed
SIGMAS = 4.0


def _stop(proc) -> tuple[int, str]:
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err


def _calibrate(ros, bag) -> dict:
    out = ros(f"python3 -m taiji2_apps.cli.main calibrate {bag} --layout type1 --json", timeout=300)
    assert out.returncode in (0, 3), out.stderr[-2000:]  # calibrated; 3: a requirement not met (short run)
    result = json.loads(out.stdout)
    assert out.returncode == (0 if result["verdict"]["all_met"] else 3)
    return result


# sqlite3, Humble's default storage (MCAP, Jazzy's default, is what the recorder's own bag and the main suite's
# foreign-writer tests cover). Each storage costs ~45 s of CI: MCAP with rosbag2's zstd preset (chunks compressed)
# ran here too until CI passed its 20-min limit (run it: pytest -m long test/rclpy with TAIJI2_RCLPY_TIER=1)
@pytest.mark.parametrize("storage,options", [
    pytest.param("mcap", "--storage-preset-profile zstd_fast", id="mcap-zstd", marks=pytest.mark.long),
    pytest.param("sqlite3", "", id="sqlite3")])
def test_ros2_bag_record_is_calibrated_and_the_recorders_bag_is_played_by_ros2_bag(ros, tmp_path, storage,
                                                                                   options):
    theirs, ours = tmp_path / "rosbag2", tmp_path / "taiji2"
    topics = " ".join(RAW_TOPICS)
    recorders = {
        "ros2 bag record": ros(f"exec ros2 bag record -s {storage} {options} --qos-profile-overrides-path "
                               f"{QOS_OVERRIDES} -o {theirs} {topics}", background=True),
        # -a: also rosbag2's /events/write_split (Jazzy's WriteSplitEvent, which Humble defines otherwise)
        "taiji2 bag record": ros(f"exec python3 -m taiji2_apps.cli.main bag record -a -o {ours}",
                                 env={"TAIJI2_RUNTIME": "cyclonedds"}, background=True),
    }
    commander = ros("exec ros2 run taiji2_sim_pkg maneuver_commander --ros-args -p use_sim_time:=true "
                    "-p lookahead_s:=2.0", background=True)
    try:
        # unclipped (the preset leaves the GRS range; clipped epochs would be gated): this test is about the bags
        sim = ros("ros2 run taiji2_sim_pkg spacecraft_sim --ros-args -p duration_s:=600.0 -p seed:=5 "
                  "-p 'wait_for_subscribers:=[2, 2, 2]' -p 'config_overrides:=[\"grs.readout_saturation=false\"]'",
                  timeout=300)
    finally:
        stopped = {name: _stop(proc) for name, proc in {**recorders, "commander": commander}.items()}
    assert sim.returncode == 0 and f"done: {SAMPLES} steps" in sim.stderr, sim.stderr[-2000:]
    for name, (status, err) in stopped.items():
        assert status == 0 and "Traceback" not in err, (name, status, err[-2000:])

    # this project's bag: every raw sample; rosbag2's with the QoS overrides (keep-all, reliable): every raw
    # sample as well (with rosbag2's default keep-last-10 reader queue it lost some whenever its writer fell
    # behind the accelerated simulator: 4-8 seen here, 23 % of the star tracker in a user's run), equal
    from taiji2_estimator_pkg.io import load_raw_bag

    mine, their = load_raw_bag(ours), load_raw_bag(theirs)
    # rosbags' AnyReader recomputes every type hash from the embedded definition (issue 26 row 4)
    from rosbags.highlevel import AnyReader

    with AnyReader([ours]) as reader:
        recorded = {c.topic: c.msgtype for c in reader.connections}
    assert set(RAW_TOPICS) <= set(recorded), recorded
    assert their.storage == storage
    for name in ("star_tracker", "grs1", "grs2"):
        a, b = (getattr(x, name) for x in (mine, their))
        assert a.stamp_ns.size == SAMPLES and b.stamp_ns.size == SAMPLES, (name, a.stamp_ns.size, b.stamp_ns.size)
        rows = np.searchsorted(a.stamp_ns, b.stamp_ns)
        assert np.array_equal(a.stamp_ns[rows], b.stamp_ns), name
        values = (lambda x: x.quat_xyzw) if name == "star_tracker" else (lambda x: x.voltages_v)
        assert np.array_equal(values(a)[rows], values(b)), name

    # both calibrated by `taiji2 calibrate` within a few sigma of the truth
    for bag, data in ((ours, mine), (theirs, their)):
        result = _calibrate(ros, bag)
        recorded = data.star_tracker.stamp_ns.size
        assert result["samples"]["scale_factor_updates"] == recorded and result["rejected"] == {}, (bag, result)
        assert result["missing"].get("star_tracker", 0) == SAMPLES - recorded, (bag, result["missing"])
        assert result["determined"], (bag, result)
        for grs in ("grs1", "grs2"):
            g, g_sigma = np.array(result[grs]["scale_factors"]), np.sqrt(np.diag(result[grs]["scale_factors_cov"]))
            d, d_sigma = np.array(result[grs]["com_offset"]), np.sqrt(np.diag(result[grs]["com_offset_cov"]))
            assert np.all(np.abs(g - TRUE_G[grs]) < SIGMAS * g_sigma), (bag, grs, g, g_sigma)
            assert np.all(np.abs(d - TRUE_D[grs]) < SIGMAS * d_sigma), (bag, grs, d, d_sigma)

    # rosbag2 reads this project's bag (`ros2 bag info`: its counts) and plays it
    info = ros(f"ros2 bag info {ours}", timeout=120)
    assert info.returncode == 0, info.stderr[-2000:]
    counts = {RAW_TOPICS[0]: mine.star_tracker.stamp_ns.size, RAW_TOPICS[3]: mine.commands.stamp_ns.size}
    for topic, count in counts.items():
        line = next(line for line in info.stdout.splitlines() if f"Topic: {topic} " in line)
        assert f"Count: {count} " in line, (topic, line, count)
    play = ros(f"exec ros2 bag play {ours} --rate 20 --loop", background=True)
    try:
        echo = ros("ros2 topic echo --once /taiji2/grs1/voltages taiji2_msgs/msg/GrsVoltages", timeout=120)
    finally:
        _stop(play)
    assert echo.returncode == 0 and "grs_id: 1" in echo.stdout and "frame_id: tmrf1" in echo.stdout, echo.stderr

    if storage == "mcap" and not options:
        # ros2 bag play with the QoS overrides at 200x into a keep-all reader (this project's recorder): lossless
        again = tmp_path / "replayed"
        recorder = ros(f"exec python3 -m taiji2_apps.cli.main bag record -o {again} {topics}",
                       env={"TAIJI2_RUNTIME": "cyclonedds"}, background=True)
        try:
            # the recorder subscribes once it sees a publisher (to learn its QoS): the player waits 5 s (--delay)
            # after creating its publishers, and at the end until the recorder acknowledged everything
            play = ros(f"ros2 bag play {theirs} --rate 200 --qos-profile-overrides-path {QOS_OVERRIDES} "
                       "--delay 5 --wait-for-all-acked 30000 --disable-keyboard-controls", timeout=180)
        finally:
            status, err = _stop(recorder)
        assert play.returncode == 0 and status == 0, (play.stderr[-2000:], err[-2000:])
        replayed = load_raw_bag(again)
        for name in ("star_tracker", "grs1", "grs2"):
            assert getattr(replayed, name).stamp_ns.size == SAMPLES, (name, getattr(replayed, name).stamp_ns.size)
