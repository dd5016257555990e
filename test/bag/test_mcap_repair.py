"""A recording cut short: the complete records of its MCAP file are read, the rest is named as lost (no DDS)."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from taiji2_estimator_pkg.io import RawBagError, load_raw_bag
from taiji2_runtime.bag.mcap_repair import MCAP_MAGIC, complete_records_end

from contract_bags import ground_segment_data, write_ground_segment_bag


def _cut(bag, fraction):
    (mcap,) = bag.glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * fraction)])
    return len(data)


def test_a_cut_mcap_gives_the_samples_before_the_cut_and_says_how_much(tmp_path, caplog):
    data = write_ground_segment_bag(tmp_path / "bag", data=ground_segment_data(n=8000))
    _cut(tmp_path / "bag", 0.7)
    with caplog.at_level(logging.WARNING, logger="taiji2.bag"):
        exp = load_raw_bag(tmp_path / "bag")
    n = len(exp.star_tracker)
    assert 0 < n < 8000  # some of the chunks were complete, the cut one is lost
    np.testing.assert_array_equal(exp.star_tracker.stamp_ns, data["stamps"][:n])  # a prefix, nothing invented
    assert len(exp.grs1) > 0 and len(exp.grs2) > 0
    (record,) = [r for r in caplog.records if "truncated MCAP" in r.getMessage()]
    assert "octets" in record.getMessage() and "messages recovered" in record.getMessage()


def test_a_file_cut_inside_its_first_chunk_is_refused_as_truncated(tmp_path):
    write_ground_segment_bag(tmp_path / "bag", data=ground_segment_data(n=8000))
    _cut(tmp_path / "bag", 0.02)
    with pytest.raises(RawBagError, match="corrupt or truncated bag"):
        load_raw_bag(tmp_path / "bag")


def test_complete_records_follow_the_lengths_and_stop_at_a_cut_record():
    record = bytes([0x01]) + (5).to_bytes(8, "little") + b"hello"
    data = MCAP_MAGIC + record + record + bytes([0x06]) + (100).to_bytes(8, "little") + b"short"
    assert complete_records_end(data) == (len(MCAP_MAGIC) + 2 * len(record), 2)
    with pytest.raises(ValueError, match="not an MCAP file"):
        complete_records_end(b"garbage")
