"""Two SDLS implementations that must agree (issue 41 item 2): a real Yamcs (5.12.8) signs a telecommand as an
SDLS-secured TC Transfer Frame on its own ``UdpTcFrameLink`` (its ``SecurityAssociationAes256Gcm128``), and the
onboard verifier (:mod:`taiji2_runtime.packets.sdls`, the SPI's service ``authenticated_encryption``) accepts
it and gives back the very packet Yamcs sent; a frame of another key, and a replay, are refused."""

from __future__ import annotations

import secrets
import socket

import pytest
from spacepackets.ecss.tc import PusTc

from taiji2_ground_pkg.mcs.commanding import COMMAND, insert_activities_arguments
from taiji2_ground_pkg.mcs.yamcs_api import connect
from taiji2_ground_pkg.mcs.yamcs_instance import FRAME_STREAM, SdlsFrameLink
from taiji2_ground_pkg.mcs.yamcs_server import YamcsServer
from taiji2_runtime.packets.scheduling import Activity, encode_insert_activities
from taiji2_runtime.packets.sdls import FrameRefused, FrameVerifier
from taiji2_runtime.packets.sdls_keys import KeyTable, SecurityAssociation

from support import YAMCS_HANG_S, free_port, require_yamcs

require_yamcs()

SPI = 3


def test_yamcs_signed_frames_are_verified_onboard(tmp_path):
    key = secrets.token_bytes(32)
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(YAMCS_HANG_S)
    frames = SdlsFrameLink(key=key, spi=SPI, port=receiver.getsockname()[1], first_sequence=1)
    server = YamcsServer(tmp_path / "yamcs", http_port=free_port(), station_port=free_port(), frames=frames)
    tables = [encode_insert_activities(k, [Activity(10**12 * (k + 1), (1e-6 * k, -2e-6, 3e-6))], k) for k in range(3)]
    server.start()
    try:
        server.wait_ready()
        client = connect(server.url.split("/")[2], server.operator_environ())
        try:
            processor = client.get_processor("taiji2", "realtime")
            issued = [processor.issue_command(COMMAND, args=insert_activities_arguments(t), stream=FRAME_STREAM)
                      for t in tables]
            received = [receiver.recv(2048) for _ in tables]
        finally:
            client.close()
    finally:
        server.stop()
        receiver.close()
    verifier = FrameVerifier(KeyTable([SecurityAssociation(SPI, key, service="authenticated_encryption")]))
    packets = [verifier.verify(frame) for frame in received]
    # the packets inside are the tables as Yamcs completed them: the planner's application data, Yamcs's sequence
    # counts, a valid CRC (spacepackets checks it) and length
    assert [p[11:-2] for p in packets] == [t[11:-2] for t in tables]
    tcs = [PusTc.unpack(p) for p in packets]
    assert len({tc.seq_count for tc in tcs}) == 3 and [(tc.service, tc.message_subtype) for tc in tcs] == [(11, 4)] * 3
    assert len(issued) == 3
    assert verifier.last_sequence[SPI] == 3  # IVs 1, 2, 3: Yamcs's counter from initialSeqNum
    with pytest.raises(FrameRefused) as replay:
        verifier.verify(received[0])
    assert replay.value.reason == "replay"
    other = FrameVerifier(KeyTable([SecurityAssociation(SPI, bytes(32), service="authenticated_encryption")]))
    with pytest.raises(FrameRefused) as forged:
        other.verify(received[1])
    assert forged.value.reason == "bad_mac"


def test_ground_serve_refuses_a_key_yamcs_cannot_sign_with_before_starting(tmp_path):
    import subprocess

    from taiji2_runtime.packets.sdls_keys import new_key_table, write_key_file

    from support import PYTHON, python_subprocess_env

    keys = write_key_file(tmp_path / "keys.json", new_key_table((1, 2), revoked=(2,)))  # the authentication service
    for extra, problem in ((["--sdls-key-file", str(keys)], "SPI 1 is of service authentication"),
                           (["--sdls-key-file", str(keys), "--sdls-spi", "2"], "--sdls-spi 2: not an active SPI"),
                           (["--sdls-key-file", str(tmp_path / "none.json")], "--sdls-key-file key file"),
                           (["--sdls-key-file", str(keys), "--frame-port", "70000"], "--frame-port 70000")):
        done = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "ground", "serve", "--data-dir",
                               str(tmp_path / "ground"), *extra], capture_output=True, text=True, timeout=120,
                              env=python_subprocess_env())
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1 and problem in lines[0], done.stderr
    assert not (tmp_path / "ground").exists()  # nothing started, nothing written
