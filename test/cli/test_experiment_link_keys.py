"""``taiji2 experiment --link`` keys (docs/security.md): a throwaway key file per run in a private temporary
directory (never the repository or --out), removed at the end; a given --key-file used as it is, a bad one named."""

from __future__ import annotations

import stat
from pathlib import Path

import pytest

from taiji2_apps.cli.experiment_link import link_key_file
from taiji2_runtime.packets.sdls_keys import REVOKED, load_key_file, new_key_table, write_key_file

REPO = Path(__file__).resolve().parents[2]


def test_a_throwaway_key_is_private_outside_the_repository_and_removed():
    path, remove = link_key_file("")
    path = Path(path)
    try:
        assert not path.is_relative_to(REPO)
        assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700 and stat.S_IMODE(path.stat().st_mode) == 0o600
        assert load_key_file(path).newest_active().spi == 1
    finally:
        remove()
    assert not path.exists() and not path.parent.exists()
    other, remove_other = link_key_file("")
    try:
        assert load_key_file(other).get(1).key != new_key_table().get(1).key  # fresh each run
    finally:
        remove_other()


def test_a_given_key_file_is_used_and_kept(tmp_path):
    given = write_key_file(tmp_path / "k.json", new_key_table((1, 2), revoked=(1,)))
    path, remove = link_key_file(str(given))
    remove()
    assert Path(path) == given.resolve() and given.exists()
    all_revoked = write_key_file(tmp_path / "r.json", new_key_table((1,), revoked=(1,)))
    with pytest.raises(ValueError, match="no active SPI"):
        link_key_file(str(all_revoked))
    with pytest.raises(ValueError, match=r"missing\.json"):
        link_key_file(str(tmp_path / "missing.json"))
    assert load_key_file(given).get(1).state == REVOKED
