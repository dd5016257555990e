"""Who may do what in the ground's Yamcs (docs/security.md): authentication on, two roles, their users.

``write_security(data_dir)`` writes ``DATA_DIR/etc/security.yaml`` (Yamcs's ``YamlAuthModule`` with its
PBKDF2 hasher), ``users.yaml`` and ``roles.yaml``, and, once per data directory, each user's credentials as
``DATA_DIR/credentials/<user>.env`` (mode 0600; ``YAMCS_USER=...`` and ``YAMCS_PASSWORD=...`` lines), which
the ground's clients read through ``YAMCS_CREDENTIALS_FILE`` (:func:`taiji2_ground_pkg.mcs.yamcs_api.connect`):

* ``operator`` (role ``Operator``): may command (the ``Command`` privilege on the taiji2 commands), set the
  ground's own parameters (estimates, link health, verdict), and read everything an observer reads. The
  planner, the ground station and ``taiji2 experiment --ground`` run as an operator.
* ``observer`` (role ``Observer``): may read packets, parameters, the command history, alarms, events and
  links, e.g. ``taiji2 calibrate yamcs://...``; Yamcs refuses its commands (403) and its parameter writes.

Anyone else is refused (Yamcs answers 401 without a login). Passwords are random (256 bits), so the hash's
iteration count (Yamcs's default, 1000) protects nothing a password of this kind needs; the hash keeps the
password itself out of ``users.yaml``. The credential files are created once and kept (rotate a password by
deleting its file and restarting the ground). Nothing is committed: every data directory makes its own.
"""

from __future__ import annotations

import hashlib
import os
import secrets
from pathlib import Path

import yaml

from taiji2_ground_pkg.mcs.xtce import SYSTEM_NAME

__all__ = ["OBSERVER", "OPERATOR", "credentials_path", "password_hash", "roles_config", "write_security"]

OPERATOR = "operator"
OBSERVER = "observer"
_ITERATIONS = 1000  # Yamcs's PBKDF2PasswordHasher default (the passwords are random 256-bit tokens)
_READ = {"ReadPacket": [".*"], "ReadParameter": [".*"], "CommandHistory": [".*"], "ReadAlgorithm": [".*"],
         "System": ["ReadCommandHistory", "GetMissionDatabase", "ReadLinks", "ReadAlarms", "ReadEvents",
                    "ReadSystemInfo"]}


def roles_config() -> dict:
    """``etc/roles.yaml``: the object privileges are regular expressions on qualified names."""
    return {
        "Operator": {**_READ, "Command": [f"/{SYSTEM_NAME}/.*"], "WriteParameter": [f"/{SYSTEM_NAME}/.*"],
                     "Stream": ["tc_.*"],  # the command streams (issuing on one names it)
                     "System": [*_READ["System"], "ControlCommandQueue", "ControlLinks", "ControlAlarms",
                                "CommandOptions"]},
        "Observer": dict(_READ),
    }


def password_hash(password: str, salt: bytes | None = None, iterations: int = _ITERATIONS) -> str:
    """Yamcs's ``PBKDF2PasswordHasher`` format: ``iterations:salt-hex:hash-hex`` (PBKDF2-HMAC-SHA1, 24 octets)."""
    salt = secrets.token_bytes(24) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha1", password.encode(), salt, iterations, 24)
    return f"{iterations}:{salt.hex()}:{digest.hex()}"


def credentials_path(data_dir: str | Path, user: str) -> Path:
    """Where ``user``'s credentials of the ground at ``data_dir`` are kept."""
    return Path(data_dir).resolve() / "credentials" / f"{user}.env"


def _credentials(data_dir: Path, user: str) -> str:
    """``user``'s password: read from its credentials file, or made and written (0600) the first time."""
    path = credentials_path(data_dir, user)
    if path.exists():
        for line in path.read_text().splitlines():
            if line.startswith("YAMCS_PASSWORD="):
                return line.split("=", 1)[1]
    password = secrets.token_urlsafe(32)
    path.parent.mkdir(mode=0o700, exist_ok=True)
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "w") as f:
        f.write(f"YAMCS_USER={user}\nYAMCS_PASSWORD={password}\n")
    return password


def write_security(data_dir: str | Path) -> dict[str, Path]:
    """Write the security configuration into ``data_dir/etc`` (and the credentials, once); returns each user's
    credentials file."""
    root = Path(data_dir).resolve()
    etc = root / "etc"
    users = {}
    for user, role in ((OPERATOR, "Operator"), (OBSERVER, "Observer")):
        users[user] = {"password": password_hash(_credentials(root, user)), "roles": [role]}
    (etc / "security.yaml").write_text(yaml.safe_dump({"authModules": [{
        "class": "org.yamcs.security.YamlAuthModule",
        "args": {"hasher": "org.yamcs.security.PBKDF2PasswordHasher", "required": True}}]}, sort_keys=False))
    descriptor = os.open(etc / "users.yaml", os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "w") as f:
        f.write(yaml.safe_dump(users, sort_keys=False))
    (etc / "roles.yaml").write_text(yaml.safe_dump(roles_config(), sort_keys=False))
    return {user: credentials_path(root, user) for user in users}
