"""SDLS key files: format, permissions, errors that name the problem and never a key (no DDS)."""

from __future__ import annotations

import json
import stat

import pytest

from taiji2_runtime.packets.sdls_keys import (
    KEY_FILE_FORMAT,
    REVOKED,
    KeyFileError,
    key_file_warning,
    load_key_file,
    new_key_table,
    write_key_file,
)


def test_write_then_load_round_trip_owner_only(tmp_path):
    table = new_key_table((1, 2, 5), revoked=(1,))
    path = write_key_file(tmp_path / "keys.json", table)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and key_file_warning(path) is None
    loaded = load_key_file(path)
    assert [(sa.spi, sa.key, sa.state) for sa in loaded] == [(sa.spi, sa.key, sa.state) for sa in table]
    assert loaded.get(1).state == REVOKED and loaded.newest_active().spi == 5
    assert table.get(2).key.hex() not in repr(table.get(2))  # a key never shows in a repr
    with pytest.raises(FileExistsError):
        write_key_file(path, table)  # never overwrites keys
    path.chmod(0o644)
    assert "readable by others" in key_file_warning(path)


def test_keys_are_fresh():
    a, b = new_key_table((1,)), new_key_table((1,))
    assert a.get(1).key != b.get(1).key and len(a.get(1).key) == 32


@pytest.mark.parametrize(("doc", "message"), [
    ("not json", "not JSON"),
    (json.dumps({"format": "other", "keys": []}), "not a taiji2-sdls-keys/1 file"),
    (json.dumps({"format": KEY_FILE_FORMAT, "keys": [{"spi": 1, "key": "00" * 16}]}), "entry 0: SPI 1: key of 16"),
    (json.dumps({"format": KEY_FILE_FORMAT, "keys": [{"spi": 0, "key": "00" * 32}]}), "reserved"),
    (json.dumps({"format": KEY_FILE_FORMAT, "keys": [{"spi": 1, "key": "zz" * 32}]}), "entry 0"),
    (json.dumps({"format": KEY_FILE_FORMAT, "keys": [{"spi": 1, "key": "00" * 32, "state": "expired"}]}),
     "state 'expired'"),
    (json.dumps({"format": KEY_FILE_FORMAT, "keys": [{"spi": 1, "key": "00" * 32}, {"spi": 1, "key": "11" * 32}]}),
     "SPI 1 twice"),
])
def test_bad_key_files_are_named(tmp_path, doc, message):
    path = tmp_path / "k.json"
    path.write_text(doc)
    with pytest.raises(KeyFileError, match=message) as e:
        load_key_file(path)
    assert "11" * 32 not in str(e.value)
    with pytest.raises(KeyFileError, match="No such file"):
        load_key_file(tmp_path / "missing.json")
