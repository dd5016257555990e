"""Bulk reading and decoding of bags against rosbags' own per-message path (no DDS)."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

from taiji2_runtime.bag import bulk_read
from taiji2_runtime.bag.bulk_decode import decode_messages, encode_messages, flatten_type
from taiji2_runtime.bag.bulk_read import RawPiece, read_raw_messages
from taiji2_runtime.bag.reading import open_reader
from taiji2_runtime.interfaces import typestore

TYPES = ["taiji2_msgs/msg/StarTracker", "taiji2_msgs/msg/GrsVoltages", "geometry_msgs/msg/WrenchStamped",
         "diagnostic_msgs/msg/KeyValue", "std_msgs/msg/Header"]


def _columns(store, msgtype, n, rng):
    """Random values for every leaf, strings of assorted lengths (0 to 12 characters)."""
    columns = {}
    for leaf in flatten_type(store, msgtype):
        if leaf.base == "string":
            columns[leaf.path] = ["".join(rng.choice(list("abcxyz01"), size=rng.integers(0, 13))) for _ in range(n)]
        elif leaf.base in ("float64", "float32"):
            shape = (n, leaf.count) if leaf.is_array else (n,)
            columns[leaf.path] = rng.normal(size=shape).astype(leaf.dtype)
        elif leaf.base == "bool":
            columns[leaf.path] = rng.integers(0, 2, size=n).astype(bool)
        else:
            info = np.iinfo(leaf.dtype)
            shape = (n, leaf.count) if leaf.is_array else (n,)
            columns[leaf.path] = rng.integers(max(info.min, -1000), min(info.max, 1000), size=shape).astype(leaf.dtype)
    return columns


def _pieces(messages, split=2):
    pieces = []
    for part in np.array_split(np.arange(len(messages)), split):
        datas = [messages[i] for i in part]
        lengths = np.array([len(d) for d in datas], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        pieces.append(RawPiece(np.frombuffer(b"".join(datas) or b"\0", np.uint8), offsets, lengths))
    return pieces


@pytest.mark.parametrize("msgtype", TYPES)
def test_encode_matches_rosbags_and_decode_inverts_it(msgtype):
    store = typestore()
    rng = np.random.default_rng(7)
    n = 200
    columns = _columns(store, msgtype, n, rng)
    messages = encode_messages(store, msgtype, columns, n)
    for raw in messages[:50]:
        assert store.serialize_cdr(store.deserialize_cdr(raw, msgtype), msgtype) == raw
    decoded = decode_messages(store, msgtype, _pieces(messages))
    assert decoded.valid.all() and not decoded.errors and decoded.bulk_rows == n
    for path, expected in columns.items():
        got = decoded.columns[path]
        if got.dtype.kind == "S":
            assert [g.decode() for g in got] == expected, path
        else:
            np.testing.assert_array_equal(got, expected, err_msg=path)


def test_unusual_messages_fall_back_or_are_reported():
    store = typestore()
    msgtype = "taiji2_msgs/msg/GrsVoltages"
    n = 30
    columns = _columns(store, msgtype, n, np.random.default_rng(1))
    columns["header.frame_id"] = ["tmrf1"] * n
    messages = encode_messages(store, msgtype, columns, n)
    big_endian = store.serialize_cdr(store.deserialize_cdr(messages[3], msgtype), msgtype, little_endian=False)
    messages[3] = big_endian                       # big-endian CDR: per-message fallback
    messages[5] = messages[5] + b"\0\0\0\0"         # 4 trailing bytes: not CDR padding, undecodable
    messages[7] = messages[7][:20]                 # truncated: undecodable
    messages[9] = messages[9][:12] + b"\xff\xff\xff\x7f" + messages[9][16:]  # absurd string length
    decoded = decode_messages(store, msgtype, _pieces(messages, split=3))
    assert set(decoded.errors) == {5, 7, 9}
    assert all(text.startswith("undecodable") for text in decoded.errors.values())
    assert decoded.valid.sum() == n - 3
    expected = np.asarray(columns["vx1"])
    ok = decoded.valid
    np.testing.assert_array_equal(decoded.columns["vx1"][ok], expected[ok])
    assert decoded.columns["header.frame_id"][3] == b"tmrf1"


@pytest.mark.parametrize("storage,compress", [("mcap", None), ("mcap", CompressionMode.STORAGE), ("sqlite3", None),
                                              ("mcap", CompressionMode.MESSAGE), ("sqlite3", CompressionMode.MESSAGE),
                                              ("sqlite3", CompressionMode.FILE)],
                         ids=["mcap", "mcap-chunks-zstd", "sqlite3", "mcap-message-zstd", "sqlite3-message-zstd",
                              "sqlite3-file-zstd"])
def test_read_raw_messages_equals_rosbags_reader(tmp_path, storage, compress):
    """Every storage and rosbag2 compression mode (chunks; each message, as `ros2 bag record
    --compression-mode message` writes; the whole file)."""
    store = typestore()
    bag = tmp_path / "bag"
    rng = np.random.default_rng(3)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(bag, version=9, storage_plugin=plugin)
    if compress is not None:
        writer.set_compression(compress, CompressionFormat.ZSTD)
    writer.open()
    connections = {t: writer.add_connection(f"/t{i}", t, typestore=store) for i, t in enumerate(TYPES[:3])}
    for k in range(3000):
        msgtype = TYPES[k % 3]
        raw = encode_messages(store, msgtype, _columns(store, msgtype, 1, rng), 1)[0]
        writer.write(connections[msgtype], 1000 + k * 7 - (k % 5), raw)
    writer.close()
    with open_reader(bag) as reader:
        bulk = read_raw_messages(reader)
        reference: dict = {}
        for connection, stamp, data in reader.messages():
            reference.setdefault((connection.topic, connection.msgtype), []).append((stamp, data))
    with Reader(bag) as reader:
        assert sum(m.count for m in bulk.values()) == reader.message_count == 3000
    for key, messages in bulk.items():
        assert messages.messages() == [d for _, d in reference[key]]
        assert messages.log_time_ns.tolist() == [s for s, _ in reference[key]]
    with open_reader(bag) as reader:
        stamps_only = read_raw_messages(reader, with_data=False)
    for key, messages in stamps_only.items():
        assert messages.log_time_ns.tolist() == bulk[key].log_time_ns.tolist()


@pytest.mark.parametrize("parts,range_bytes", [(1, 2**28), (2, 2**28), (3, 2**28), (7, 2**28), (2, 4096)])
def test_sqlite3_aggregate_read_orders_ties_and_keeps_empty_topics(tmp_path, monkeypatch, parts, range_bytes):
    """sqlite3: messages of equal stamps stay in insertion (id) order, rows interleaved across topics
    are separated, a topic without messages is listed empty; bytes as rosbags reads them. The same
    whatever the number of id ranges the table scan is split into (as many as the machine has cores,
    more for a big file), ties and descending stamps straddling the ranges' borders included."""
    monkeypatch.setattr(bulk_read, "_SQLITE_PARTS", parts)
    monkeypatch.setattr(bulk_read, "_SQLITE_RANGE_BYTES", range_bytes)
    store = typestore()
    bag = tmp_path / "bag"
    writer = Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3)
    writer.open()
    used = writer.add_connection("/a", TYPES[1], typestore=store)
    other = writer.add_connection("/b", TYPES[0], typestore=store)
    writer.add_connection("/silent", TYPES[2], typestore=store)
    rng = np.random.default_rng(5)
    for k in range(400):
        connection, msgtype = (used, TYPES[1]) if k % 3 else (other, TYPES[0])
        raw = encode_messages(store, msgtype, _columns(store, msgtype, 1, rng), 1)[0]
        writer.write(connection, 5000 - 10 * (k // 7), raw)  # stamps descending in blocks of 7 equal ones
    writer.close()
    with open_reader(bag) as reader:
        bulk = read_raw_messages(reader)
        reference: dict = {}
        for connection, stamp, data in reader.messages():
            reference.setdefault(connection.topic, []).append((stamp, data))
    by_topic = {key[0]: value for key, value in bulk.items()}
    assert by_topic["/silent"].count == 0 and by_topic["/silent"].messages() == []
    for topic in ("/a", "/b"):
        assert by_topic[topic].log_time_ns.tolist() == [s for s, _ in reference[topic]]
        assert by_topic[topic].messages() == [d for _, d in reference[topic]]


@pytest.mark.parametrize("stamp", ["1205.5", "'abc'"])
def test_sqlite3_rows_the_aggregate_cannot_take_are_read_as_rosbags_reads_them(tmp_path, stamp):
    """A row whose stamp is not an integer leaves the aggregate path: a real is read as rosbags'
    reader reads it (stamps as integers, same bytes, same order); text is a one-line error naming
    the bag."""
    import apsw

    from taiji2_runtime.bag.errors import BagError

    store = typestore()
    bag = tmp_path / "bag"
    writer = Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3)
    writer.open()
    connection = writer.add_connection("/a", TYPES[1], typestore=store)
    rng = np.random.default_rng(11)
    for k in range(50):
        raw = encode_messages(store, TYPES[1], _columns(store, TYPES[1], 1, rng), 1)[0]
        writer.write(connection, 1000 + 10 * k, raw)
    writer.close()
    (db3,) = bag.glob("*.db3")
    db = apsw.Connection(str(db3))
    db.execute(f"UPDATE messages SET timestamp = {stamp} WHERE id = 21")
    db.close()
    with open_reader(bag) as reader:
        if stamp == "'abc'":
            with pytest.raises(BagError, match="bag"):
                read_raw_messages(reader)
            return
        bulk = read_raw_messages(reader)
        reference = [(stamp, data) for _, stamp, data in reader.messages()]
    (messages,) = bulk.values()
    assert messages.count == 50
    assert messages.log_time_ns.tolist() == [int(s) for s, _ in reference]
    assert 1205 in messages.log_time_ns.tolist()
    assert messages.messages() == [bytes(d) for _, d in reference]
