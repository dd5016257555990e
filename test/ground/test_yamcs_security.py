"""Who may command in the ground's Yamcs (issue 41 item 3), against a real Yamcs started as ``taiji2 ground
serve`` starts it: authentication on; the operator may command and set the ground's parameters; the observer
may read the archive (``taiji2 calibrate yamcs://...`` works with its credentials) but Yamcs refuses its
command and its parameter write; no login is refused; credentials come from the environment or a file."""

from __future__ import annotations

import os
import stat

import pytest

from taiji2_ground_pkg.mcs.errors import GroundError
from taiji2_ground_pkg.mcs.yamcs_api import (
    UNAUTHORIZED,
    archived_packets,
    connect,
    credentials,
    instance_state,
    set_parameters,
)
from taiji2_ground_pkg.mcs.yamcs_security import OBSERVER, OPERATOR, password_hash

from support import require_yamcs, running_yamcs

require_yamcs()


@pytest.fixture(scope="module")
def yamcs(tmp_path_factory):
    with running_yamcs(tmp_path_factory.mktemp("yamcs")) as server:
        yield server


def _as(server, user):
    return {"YAMCS_CREDENTIALS_FILE": str(server.credentials_file(user))}


def _issue(server, user):
    """Issue one insert_activities (a valid table) as ``user``; the Yamcs error, or None if accepted."""
    from taiji2_ground_pkg.mcs.commanding import COMMAND, insert_activities_arguments
    from taiji2_runtime.packets.scheduling import Activity, encode_insert_activities

    client = connect(server.url.split("/")[2], _as(server, user))
    try:
        processor = client.get_processor("taiji2", "realtime")
        table = encode_insert_activities(0, [Activity(10**12, (1e-6, 0.0, 0.0))])
        processor.issue_command(COMMAND, args=insert_activities_arguments(table), dry_run=True)
    except Exception as exc:  # yamcs-client raises its own types (Unauthorized/YamcsError with the status)
        return exc
    finally:
        client.close()
    return None


def test_the_operator_may_command_and_the_observer_may_not(yamcs):
    assert _issue(yamcs, OPERATOR) is None
    refused = _issue(yamcs, OBSERVER)
    assert refused is not None and "403" in str(refused), refused  # Forbidden: no Command privilege


def test_the_observer_reads_but_may_not_set_the_grounds_parameters(yamcs):
    url = yamcs.url
    set_parameters(url, {"grs1_G_Pphi": 7.4e-8})  # the operator (the environment running_yamcs set)
    os.environ["YAMCS_CREDENTIALS_FILE"] = str(yamcs.credentials_file(OBSERVER))
    try:
        with pytest.raises(GroundError, match="cannot set parameters"):
            set_parameters(url, {"grs1_G_Pphi": 1.0})
        client = connect(url.split("/")[2])
        try:
            value = client.get_processor("taiji2", "realtime").get_parameter_value("/taiji2/grs1_G_Pphi")
        finally:
            client.close()
        assert value.eng_value == 7.4e-8  # read, and unchanged by the refused write
        assert archived_packets(url) == []  # the archive (empty here) is the observer's to read, as calibrate does
    finally:
        os.environ["YAMCS_CREDENTIALS_FILE"] = str(yamcs.credentials_file(OPERATOR))


def test_without_a_login_yamcs_answers_unauthorized(yamcs):
    assert instance_state(yamcs.http_port, environ={}) == UNAUTHORIZED
    wrong = yamcs.credentials_file(OPERATOR).with_name("wrong.env")
    wrong.write_text("YAMCS_USER=operator\nYAMCS_PASSWORD=not-the-password\n")
    assert instance_state(yamcs.http_port, environ={"YAMCS_CREDENTIALS_FILE": str(wrong)}) == UNAUTHORIZED
    assert instance_state(yamcs.http_port, environ=_as(yamcs, OBSERVER)) == "RUNNING"


def test_credentials_are_private_files_and_hashed_in_yamcs(yamcs):
    for user in (OPERATOR, OBSERVER):
        path = yamcs.credentials_file(user)
        assert stat.S_IMODE(path.stat().st_mode) == 0o600 and stat.S_IMODE(path.parent.stat().st_mode) == 0o700
        password = credentials({"YAMCS_CREDENTIALS_FILE": str(path)})[1]
        users = (yamcs.data_dir / "etc" / "users.yaml").read_text()
        assert password not in users and len(password) >= 43  # 256 random bits, only its hash in users.yaml
    assert stat.S_IMODE((yamcs.data_dir / "etc" / "users.yaml").stat().st_mode) == 0o600


def test_password_hash_is_yamcs_pbkdf2_format():
    # PBKDF2-HMAC-SHA1, 1000 iterations, 24-octet salt and hash, as org.yamcs.security.PBKDF2PasswordHasher
    # writes it: RFC 6070 vector 2 (P = "password", S = "salt", c = 2, dkLen 20) checks the primitive
    assert password_hash("password", b"salt", 2).split(":")[2][:40] == "ea6c014dc72d6f8ccd1ed92ace1d41f0d8de8957"
    iterations, salt, digest = password_hash("x").split(":")
    assert iterations == "1000" and len(bytes.fromhex(salt)) == 24 and len(bytes.fromhex(digest)) == 24


def test_credentials_come_from_the_environment_or_a_file(tmp_path):
    assert credentials({"YAMCS_USER": "u", "YAMCS_PASSWORD": "p"}) == ("u", "p")
    assert credentials({}) is None
    good = tmp_path / "c.env"
    good.write_text("YAMCS_USER=operator\nYAMCS_PASSWORD=a=b\n")
    assert credentials({"YAMCS_CREDENTIALS_FILE": str(good)}) == ("operator", "a=b")
    bad = tmp_path / "bad.env"
    bad.write_text("YAMCS_USER=operator\n")
    for path, problem in ((bad, "needs YAMCS_USER"), (tmp_path / "none.env", "cannot be read")):
        with pytest.raises(GroundError, match=problem) as info:
            credentials({"YAMCS_CREDENTIALS_FILE": str(path)})
        assert str(path) in str(info.value)
