"""SDLS key files and the key table (the security associations' keys, selected by SPI; docs/security.md).

A key file is JSON, kept **outside the repository** (none is committed) and readable by its owner only::

    {"format": "taiji2-sdls-keys/1",
     "keys": [{"spi": 1, "key": "<64 hex digits: a 256-bit AES key>", "state": "revoked"},
              {"spi": 2, "key": "<64 hex digits>", "state": "active"}]}

``state`` is ``active`` or ``revoked``: the onboard side refuses every frame of a revoked SPI, the ground signs
with an active one (by default the highest active SPI: keys rotate by adding a new SPI and revoking the old).
``service`` (optional) is the SDLS service of the SPI: ``authentication`` (the default: the data in the clear,
the MAC over the headers and the data) or ``authenticated_encryption`` (the data encrypted, the MAC over the
masked header, as Yamcs's ``SecurityAssociationAes256Gcm128`` makes frames; :mod:`.sdls`).
SPI 0 and 0xFFFF are reserved (no security association). :func:`write_key_file` makes one (mode 0600).
"""

from __future__ import annotations

import json
import os
import secrets
import stat
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["ACTIVE", "AUTHENTICATED_ENCRYPTION", "AUTHENTICATION", "KEY_FILE_FORMAT", "KEY_OCTETS", "REVOKED",
           "SERVICES", "KeyFileError", "KeyTable", "SecurityAssociation", "key_file_warning", "load_key_file",
           "new_key_table", "write_key_file"]

KEY_FILE_FORMAT = "taiji2-sdls-keys/1"
KEY_OCTETS = 32  # AES-256
ACTIVE = "active"
REVOKED = "revoked"
_STATES = (ACTIVE, REVOKED)
AUTHENTICATION = "authentication"
AUTHENTICATED_ENCRYPTION = "authenticated_encryption"
SERVICES = (AUTHENTICATION, AUTHENTICATED_ENCRYPTION)


class KeyFileError(ValueError):
    """A key file that cannot be used; the message names the file and what is wrong (never a key)."""


@dataclass(frozen=True)
class SecurityAssociation:
    """One SPI's key, state and SDLS service (the key is left out of the repr)."""

    spi: int
    key: bytes = field(repr=False)
    state: str = ACTIVE
    service: str = AUTHENTICATION

    def __post_init__(self) -> None:
        if not 0 < self.spi < 0xFFFF:
            raise ValueError(f"SPI {self.spi}: 1..65534 (0 and 0xFFFF are reserved)")
        if len(self.key) != KEY_OCTETS:
            raise ValueError(f"SPI {self.spi}: key of {len(self.key)} octets, AES-256 needs {KEY_OCTETS}")
        if self.state not in _STATES:
            raise ValueError(f"SPI {self.spi}: state {self.state!r}, one of {', '.join(_STATES)}")
        if self.service not in SERVICES:
            raise ValueError(f"SPI {self.spi}: service {self.service!r}, one of {', '.join(SERVICES)}")


class KeyTable:
    """The security associations by SPI."""

    def __init__(self, associations: Iterable[SecurityAssociation] = ()) -> None:
        self._by_spi: dict[int, SecurityAssociation] = {}
        for sa in associations:
            if sa.spi in self._by_spi:
                raise ValueError(f"SPI {sa.spi} twice")
            self._by_spi[sa.spi] = sa

    def get(self, spi: int) -> SecurityAssociation | None:
        return self._by_spi.get(spi)

    def __iter__(self):  # noqa: ANN204 - an iterator of SecurityAssociation
        return iter(sorted(self._by_spi.values(), key=lambda sa: sa.spi))

    def __len__(self) -> int:
        return len(self._by_spi)

    def newest_active(self) -> SecurityAssociation:
        """The active association of the highest SPI (ValueError if none is active)."""
        active = [sa for sa in self._by_spi.values() if sa.state == ACTIVE]
        if not active:
            raise ValueError("no active SPI in the key table")
        return max(active, key=lambda sa: sa.spi)

    def with_state(self, spi: int, state: str) -> KeyTable:
        """A copy with ``spi``'s state changed (KeyError if unknown)."""
        sa = self._by_spi[spi]
        return KeyTable([*(s for s in self._by_spi.values() if s.spi != spi),
                         SecurityAssociation(spi, sa.key, state, sa.service)])

    def to_json(self) -> str:
        def entry(sa: SecurityAssociation) -> dict:
            extra = {} if sa.service == AUTHENTICATION else {"service": sa.service}
            return {"spi": sa.spi, "key": sa.key.hex(), "state": sa.state, **extra}

        return json.dumps({"format": KEY_FILE_FORMAT, "keys": [entry(sa) for sa in self]}, indent=1) + "\n"


def new_key_table(spis: Iterable[int] = (1,), revoked: Iterable[int] = ()) -> KeyTable:
    """Fresh random keys (``secrets``) for ``spis``; those in ``revoked`` marked revoked."""
    revoked = set(revoked)
    return KeyTable(SecurityAssociation(s, secrets.token_bytes(KEY_OCTETS), REVOKED if s in revoked else ACTIVE)
                    for s in spis)


def write_key_file(path: str | Path, table: KeyTable) -> Path:
    """Write ``table`` to a new file readable by its owner only (FileExistsError if it exists)."""
    path = Path(path)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(table.to_json())
    return path


def load_key_file(path: str | Path) -> KeyTable:
    """The key table of a key file.

    Raises
    ------
    KeyFileError
        The file is missing, not JSON, of another format, or has a bad entry (named by its index and SPI).
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise KeyFileError(f"key file {path}: {exc.strerror or exc}") from None
    except ValueError:
        raise KeyFileError(f"key file {path}: not JSON") from None
    if not isinstance(doc, dict) or doc.get("format") != KEY_FILE_FORMAT or not isinstance(doc.get("keys"), list):
        raise KeyFileError(f"key file {path}: not a {KEY_FILE_FORMAT} file (format and keys)")
    out = []
    for k, entry in enumerate(doc["keys"]):
        try:
            if not isinstance(entry, dict) or set(entry) - {"spi", "key", "state", "service"}:
                raise ValueError("an object of spi, key, state and optionally service")
            spi, key = entry["spi"], entry["key"]
            if not isinstance(spi, int) or not isinstance(key, str):
                raise ValueError("spi an integer, key hex digits")
            out.append(SecurityAssociation(spi, bytes.fromhex(key), entry.get("state", ACTIVE),
                                           entry.get("service", AUTHENTICATION)))
        except (KeyError, ValueError) as exc:
            raise KeyFileError(f"key file {path}: entry {k}: {exc}") from None
    try:
        return KeyTable(out)
    except ValueError as exc:
        raise KeyFileError(f"key file {path}: {exc}") from None


def key_file_warning(path: str | Path) -> str | None:
    """A warning if ``path`` is readable by its group or others (the keys are secrets), else None."""
    try:
        mode = Path(path).stat().st_mode
    except OSError:
        return None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        return f"key file {path} is readable by others (mode {stat.S_IMODE(mode):o}): chmod 600 it"
    return None
