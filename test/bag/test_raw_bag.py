"""load_raw_bag on bags written by other tools, structural problems, and bad bags (no DDS)."""

from __future__ import annotations

import os
import shutil
import subprocess
import time

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from taiji2_estimator_pkg.io import RawBagError, load_raw_bag
from taiji2_runtime.bag.bulk_decode import encode_messages

from contract_bags import CMD, GRS, ST, TOPICS, write_ground_segment_bag
from support import PYTHON, REPO, python_subprocess_env


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_ground_segment_bag_loads_exactly(tmp_path, storage):
    data = write_ground_segment_bag(tmp_path / "bag", storage)
    exp = load_raw_bag(tmp_path / "bag")
    assert exp.storage == storage and exp.custom_data == {}
    assert all(report.clean for report in exp.report.values()), exp.report_lines()
    np.testing.assert_array_equal(exp.star_tracker.stamp_ns, data["stamps"])
    np.testing.assert_allclose(exp.star_tracker.t_s, data["stamps"] / 1e9, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(exp.star_tracker.quat_xyzw, data["quat"])
    np.testing.assert_array_equal(exp.star_tracker.cov_rad2, data["cov"])
    np.testing.assert_array_equal(exp.star_tracker.receive_ns, data["stamps"] + 1000)
    for i, grs in enumerate((exp.grs1, exp.grs2)):
        assert grs.grs_id == i + 1 and grs.frame_id == f"tmrf{i + 1}"
        np.testing.assert_array_equal(grs.voltages_v, data["volts"][i])
        np.testing.assert_array_equal(grs.stamp_ns, data["stamps"])
    np.testing.assert_array_equal(exp.commands.torque_n_m, data["torque"])
    np.testing.assert_array_equal(exp.commands.stamp_ns, data["stamps"][::10])
    # a single storage file without metadata.yaml opens too
    single = next((tmp_path / "bag").glob("*.mcap" if storage == "mcap" else "*.db3"))
    assert len(load_raw_bag(single).grs2) == len(data["stamps"])


def _contract_bag_with_problems(path, storage="mcap", split_at=()):
    """Our own writer with hand-made structural problems on every raw topic, and custom data; a new
    storage file (segment) from each epoch in ``split_at``."""
    from taiji2_runtime.bag.writer import BagWriter
    from taiji2_runtime.interfaces import typestore

    store = typestore()
    writer = BagWriter(path, store, storage=storage)
    writer.set_custom_data("taiji2.seed", "11")
    handles = {t: writer.add_topic(t, mt) for t, mt in TOPICS.items()}
    wrong = writer.add_topic("/taiji2/maneuver/command", "geometry_msgs/msg/Vector3Stamped")
    stamps = [0, 1, 2, 2, 3, 1, 4, 5]  # a duplicate (2) and an out-of-order stamp (1)
    for k, sec in enumerate(stamps):
        if k in split_at:  # the segment's wall-time period is over
            writer.poll(time.monotonic() + 3600.0)
        st = encode_messages(store, ST, {"header.stamp.sec": sec, "header.frame_id": "crf", "attitude.w": 1.0}, 1)[0]
        writer.write(handles["/taiji2/star_tracker"], k, st[:30] if k == 7 else st)  # last one truncated
        for i, topic in enumerate(("/taiji2/grs1/voltages", "/taiji2/grs2/voltages")):
            frame = "tmrf2" if (i == 0 and k == 3) else f"tmrf{i + 1}"
            grs_id = 1 if (i == 1 and k == 4) else i + 1
            writer.write(handles[topic], k, encode_messages(store, GRS, {
                "header.stamp.sec": k, "header.frame_id": frame, "grs_id": grs_id, "vx1": float(k)}, 1)[0])
        writer.write(handles["/taiji2/maneuver/command"], k, encode_messages(
            store, CMD, {"header.stamp.sec": k, "header.frame_id": "crf"}, 1)[0])
    writer.write(wrong, 9, encode_messages(store, "geometry_msgs/msg/Vector3Stamped", {"header.frame_id": "crf"},
                                           1)[0])
    writer.close()


def test_structural_problems_are_counted_per_topic(tmp_path):
    _contract_bag_with_problems(tmp_path / "bag")
    exp = load_raw_bag(tmp_path / "bag")
    st = exp.report["/taiji2/star_tracker"]
    assert st.dropped == {"undecodable": 1} and st.loaded == 7
    assert st.flagged == {"duplicate_stamp": 1, "out_of_order_stamp": 1}
    assert exp.star_tracker.stamp_ns.tolist() == [s * 10**9 for s in [0, 1, 2, 2, 3, 1, 4]]  # kept, bag order
    g1, g2 = exp.report["/taiji2/grs1/voltages"], exp.report["/taiji2/grs2/voltages"]
    assert g1.dropped == {"frame_id_mismatch": 1} and "tmrf2" in g1.line()
    assert g2.dropped == {"grs_id_mismatch": 1}
    assert 3.0 not in exp.grs1.voltages_v[:, 0] and 4.0 not in exp.grs2.voltages_v[:, 0]
    cmd = exp.report["/taiji2/maneuver/command"]
    assert cmd.dropped == {"wrong_type": 1} and cmd.loaded == 8
    assert set(cmd.found_types) == {CMD, "geometry_msgs/msg/Vector3Stamped"}


def _humble_era_sqlite3(path):
    """rosbags' writer, made into what rosbag2 on Humble writes: metadata version 5, sqlite3 schema 3,
    no type hashes and no embedded message definitions."""
    import sqlite3

    import yaml

    write_ground_segment_bag(path, "sqlite3")
    with sqlite3.connect(next(path.glob("*.db3"))) as db:
        db.execute("UPDATE schema SET schema_version = 3")
        db.execute("DROP TABLE message_definitions")
    meta = yaml.safe_load((path / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    info["version"] = 5
    for entry in info["topics_with_message_count"]:
        entry["topic_metadata"].pop("type_description_hash", None)
    (path / "metadata.yaml").write_text(yaml.safe_dump(meta))


def _assert_same_experiment(a, b):
    assert (a.storage, a.custom_data, a.report_lines()) == (b.storage, b.custom_data, b.report_lines())
    for name in ("star_tracker", "grs1", "grs2", "commands"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        for field_name, value in ({} if x is None else vars(x)).items():
            if isinstance(value, np.ndarray):
                np.testing.assert_array_equal(value, getattr(y, field_name), err_msg=f"{name}.{field_name}")
            else:
                assert value == getattr(y, field_name), (name, field_name)


@pytest.mark.parametrize("make,files", [
    (lambda p: write_ground_segment_bag(p, "sqlite3"), 1),
    (lambda p: _contract_bag_with_problems(p, "sqlite3", split_at=(3, 6)), 3),
    (_humble_era_sqlite3, 1),
])
def test_sqlite3_direct_open_reads_as_rosbags_reader(tmp_path, monkeypatch, make, files):
    """A sqlite3 directory bag is read without rosbags' Reader (no per-topic count scan on opening):
    the same arrays, reports, storage and custom data as through rosbags' Reader, for rosbags' own
    writer (version 8, and made into a Humble-era bag) and ours (three files, custom data, a wrong
    type, an undecodable message, duplicate and out-of-order stamps, foreign frames and ids)."""
    from taiji2_estimator_pkg.io import raw_bag
    from taiji2_runtime.bag.sqlite3_direct import open_sqlite3_bag

    bag = tmp_path / "bag"
    make(bag)
    opened = open_sqlite3_bag(bag)
    assert opened is not None and opened.files, "the direct path was not taken"
    assert len(opened.files) == files, opened.files
    direct = load_raw_bag(bag)
    monkeypatch.setattr(raw_bag, "open_sqlite3_bag", lambda _bag: None)
    _assert_same_experiment(direct, load_raw_bag(bag))


def _truncate(bag):
    target = next(bag.glob("*.mcap"))
    target.write_bytes(target.read_bytes()[: target.stat().st_size // 2])


def _truncate_sqlite(bag):
    target = next(bag.glob("*.db3"))
    target.write_bytes(target.read_bytes()[: target.stat().st_size // 2])


def _randomize(bag):
    target = next(bag.glob("*.mcap"))
    target.write_bytes(np.random.default_rng(0).bytes(target.stat().st_size))


def _random_sqlite(bag):
    target = next(bag.glob("*.db3"))
    target.write_bytes(np.random.default_rng(0).bytes(target.stat().st_size))


def _different_definition(path, storage="mcap"):
    """A bag whose embedded StarTracker definition is not the contract's (an extra field first)."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    text = "uint32 sequence\n" + (REPO / "src/taiji2_msgs/msg/StarTracker.msg").read_text()
    store.register(get_types_from_msg(text, ST))
    for name in ("GrsVoltages",):
        store.register(get_types_from_msg((REPO / f"src/taiji2_msgs/msg/{name}.msg").read_text(),
                                          f"taiji2_msgs/msg/{name}"))
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        for topic, msgtype in TOPICS.items():
            conn = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conn, 1, store.serialize_cdr(_default(store, msgtype), msgtype))


def _default(store, msgtype):
    import dataclasses

    cls = store.types[msgtype]
    values = {}
    for f in dataclasses.fields(cls):
        if f.name == "__msgtype__":
            continue
        kind, args = dict(store.fielddefs[msgtype][1])[f.name]
        if kind == 2:
            values[f.name] = _default(store, args)
        elif kind == 3:
            values[f.name] = np.zeros(args[1])
        else:
            values[f.name] = "" if args[0] == "string" else 0
    return cls(**values)


BAD_BAGS = {
    "truncated mcap": (lambda p: (write_ground_segment_bag(p), _truncate(p)), "corrupt or truncated"),
    "random bytes mcap": (lambda p: (write_ground_segment_bag(p), _randomize(p)), "corrupt"),
    "random bytes sqlite3": (lambda p: (write_ground_segment_bag(p, "sqlite3"), _random_sqlite(p)), "corrupt"),
    "empty directory": (lambda p: p.mkdir(), "directory is empty"),
    "no metadata.yaml": (lambda p: (write_ground_segment_bag(p), (p / "metadata.yaml").unlink()),
                         "no metadata.yaml"),
    "broken metadata.yaml": (lambda p: (write_ground_segment_bag(p), (p / "metadata.yaml").write_text("{: [")),
                             "corrupt"),
    "not a bag file": (lambda p: p.write_text("hello"), "not a ROS 2 bag"),
    "does not exist": (lambda p: None, "does not exist"),
    "missing grs2 topic": (lambda p: write_ground_segment_bag(p, skip=("/taiji2/grs2/voltages",)),
                           "missing raw topic /taiji2/grs2/voltages"),
    "wrong type on the star tracker": (
        lambda p: write_ground_segment_bag(
            p, overrides={"/taiji2/star_tracker": "geometry_msgs/msg/QuaternionStamped"}),
        "has type geometry_msgs/msg/QuaternionStamped, expected taiji2_msgs/msg/StarTracker"),
    "different embedded definition": (_different_definition, "differs from the installed one"),
    # sqlite3 directory bags are read without rosbags' Reader while they are sound: when they are not,
    # the errors are rosbags' as for any other bag
    "truncated sqlite3": (lambda p: (write_ground_segment_bag(p, "sqlite3"), _truncate_sqlite(p)), "corrupt"),
    "missing grs2 topic sqlite3": (lambda p: write_ground_segment_bag(p, "sqlite3", skip=("/taiji2/grs2/voltages",)),
                                   "missing raw topic /taiji2/grs2/voltages"),
    "different embedded definition sqlite3": (lambda p: _different_definition(p, "sqlite3"),
                                              "differs from the installed one"),
    "sqlite3 file missing": (lambda p: (write_ground_segment_bag(p, "sqlite3"), next(p.glob("*.db3")).unlink()),
                             "missing"),
}


@pytest.mark.parametrize("case", sorted(BAD_BAGS))
def test_bad_bags_give_one_line_errors(tmp_path, case):
    make, expected = BAD_BAGS[case]
    path = tmp_path / "bag"
    make(path)
    with pytest.raises(RawBagError) as info:
        load_raw_bag(path)
    message = str(info.value)
    assert isinstance(info.value, ValueError)
    assert "\n" not in message and str(path) in message and expected in message, message


@pytest.mark.parametrize("case", ["truncated mcap", "random bytes sqlite3", "empty directory", "no metadata.yaml"])
@pytest.mark.parametrize("verb", ["info", "play"])
def test_cli_bad_bags_one_line_no_traceback(tmp_path, case, verb):
    make, _expected = BAD_BAGS[case]
    path = tmp_path / "bag"
    make(path)
    env = python_subprocess_env()
    env["ROS_DOMAIN_ID"] = os.environ["ROS_DOMAIN_ID"]
    result = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "bag", verb, str(path)],
                            capture_output=True, text=True, timeout=60, env=env)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: taiji2 bag: {path}"), result.stderr


def test_optional_topics_may_be_absent(tmp_path):
    write_ground_segment_bag(tmp_path / "bag", skip=("/taiji2/maneuver/command",))
    exp = load_raw_bag(tmp_path / "bag", required=("/taiji2/star_tracker", "/taiji2/grs1/voltages",
                                                   "/taiji2/grs2/voltages"))
    assert exp.commands is None and exp.report["/taiji2/maneuver/command"].messages == 0
    with pytest.raises(RawBagError, match="missing raw topic /taiji2/maneuver/command"):
        load_raw_bag(tmp_path / "bag")
    shutil.rmtree(tmp_path / "bag")


@pytest.mark.parametrize("store", [Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY])
def test_contract_typestore_has_the_standard_definitions(store):
    """The light store raw bags are read with defines the standard types as ROS 2 does."""
    from taiji2_runtime.typestore import CONTRACT_STANDARD_DEFINITIONS, contract_typestore

    standard = get_typestore(store)
    for msgtype in CONTRACT_STANDARD_DEFINITIONS:
        assert contract_typestore().fielddefs[msgtype] == standard.fielddefs[msgtype], msgtype
