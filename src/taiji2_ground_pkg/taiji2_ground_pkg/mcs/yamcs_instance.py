"""The Yamcs configuration of the ground station: one instance, ``taiji2``, written into a data directory.

``write_instance(data_dir, ...)`` writes ``DATA_DIR/etc`` (``yamcs.yaml``, ``yamcs.taiji2.yaml``,
``processor.yaml``), ``DATA_DIR/mdb/taiji2.xml`` (the XTCE database of :mod:`.xtce`, generated, never
edited) and the archive lives in ``DATA_DIR/yamcs-data`` (Yamcs's RocksDB; kept across restarts, as an
operator's archive is).

The instance, as an operator's ground station has it:

* HTTP API and web interface on ``127.0.0.1:HTTP_PORT`` (``yamcs://127.0.0.1:HTTP_PORT/taiji2``);
* one data link, ``ground-station`` (Yamcs's ``TcpTcTmDataLink``): Yamcs connects to the ground station
  front end (:mod:`.station`) at ``127.0.0.1:STATION_PORT`` and reads the CCSDS Space Packets the ground
  received, in reception order, on one TCP connection (a busy machine does not drop what TCP carries);
  telecommands go back on the same connection, completed by Yamcs's ``PusCommandPostprocessor`` (length,
  sequence count, CRC-16-CCITT). Yamcs retries the connection every 10 s;
* the packets' preprocessing: ``GenericPacketPreprocessor`` with the CUC time at offset 6 (its P-field in
  the packet, read by Yamcs), the mission epoch ``MISSION_EPOCH_UTC`` for the onboard clock's zero, the
  APID and sequence count as the archive's sequence number, and the CRC-16-CCITT of the last two octets
  (a packet whose CRC fails is archived as invalid, never decoded);
* archiving: the packets (``XtceTmRecorder``), the parameters, the command history, the alarms and the
  events; the parameter archive filled in real time;
* authentication on: an operator who may command and an observer who may only read
  (:mod:`.yamcs_security`).
"""

from __future__ import annotations

import os
import secrets
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from taiji2_ground_pkg.mcs.xtce import ROOT_CONTAINER, SYSTEM_NAME, write_xtce
from taiji2_ground_pkg.mcs.yamcs_security import write_security
from taiji2_runtime.packets.sdls import IV_OCTETS
from taiji2_runtime.packets.tc_frame import MAX_FRAME_OCTETS, SPACECRAFT_ID, TC_VCID

__all__ = ["FRAME_LINK_NAME", "FRAME_STREAM", "INSTANCE", "LINK_NAME", "MISSION_EPOCH_UTC", "SdlsFrameLink",
           "instance_config", "processor_config", "server_config", "write_instance"]

INSTANCE = "taiji2"
#: the data link that reads the ground station front end
LINK_NAME = "ground-station"
#: the onboard clock's zero (the CUC P-field's agency-defined epoch) as Yamcs shows it: packet times are
#: this plus the onboard time. A convention of the emulation; a mission sets its own
MISSION_EPOCH_UTC = "2035-01-01T00:00:00Z"
#: where the CUC time (its P-field first) sits in a packet [octets]
_CUC_OFFSET = 6
#: Yamcs reads a packet's "sequence number" as the 4 octets at this offset and archives a packet under its
#: generation time and that number, whatever its APID: from offset 0 the number holds the APID and the
#: sequence count (as Yamcs's own CCSDS preprocessor takes it), so the two GRS's packets of one instant,
#: which share time and count, are two packets, not one stored over the other
_SEQUENCE_NUMBER_OFFSET = 0


def server_config(http_port: int) -> dict:
    """``etc/yamcs.yaml``: the HTTP server on localhost and the one instance (the archive directory is
    the server's ``--data-dir``)."""
    return {
        "services": [{"class": "org.yamcs.http.HttpServer", "args": {"address": "127.0.0.1", "port": int(http_port)}}],
        "instances": [INSTANCE],
        # signs the web interface's session tokens; a fresh one per data directory
        "secretKey": secrets.token_hex(32),
    }


@dataclass(frozen=True)
class SdlsFrameLink:
    """Yamcs's own SDLS-secured TC frames (its ``UdpTcFrameLink``, one frame per UDP datagram to
    ``127.0.0.1:port``): the key of ``spi`` (written raw into ``etc/``, mode 0600, as Yamcs reads it), its IV
    counter from ``first_sequence`` (Yamcs keeps it in the instance's database across restarts). Commands
    issued on the stream :data:`FRAME_STREAM` go out this way (authenticated encryption: Yamcs 5.12.8 has no
    authentication-only service; docs/security.md)."""

    key: bytes = field(repr=False)
    spi: int
    port: int
    first_sequence: int = 1


#: the stream of the commands Yamcs sends as SDLS-secured frames (with an :class:`SdlsFrameLink`)
FRAME_STREAM = "tc_frames"
#: the frame link's name
FRAME_LINK_NAME = "ground-station-frames"


def _frame_link(frames: SdlsFrameLink, key_file: str) -> dict:
    return {
        "name": FRAME_LINK_NAME,
        "class": "org.yamcs.tctm.ccsds.UdpTcFrameLink",
        "host": "127.0.0.1",
        "port": int(frames.port),
        "spacecraftId": SPACECRAFT_ID,
        "maxFrameLength": MAX_FRAME_OCTETS,
        "errorDetection": "CRC16",
        "encryption": [{"spi": int(frames.spi),
                        "class": "org.yamcs.security.sdls.SecurityAssociationAes256Gcm128Factory",
                        "args": {"keyFile": key_file,
                                 "initialSeqNum": frames.first_sequence.to_bytes(IV_OCTETS, "big").hex()}}],
        "virtualChannels": [{
            "vcId": TC_VCID, "service": "PACKET", "encryptionSpi": int(frames.spi), "stream": FRAME_STREAM,
            "multiplePacketsPerFrame": False, "useCop1": False,  # one whole packet per Type-BD frame, as ours
            "commandPostprocessorClassName": "org.yamcs.pus.PusCommandPostprocessor",
            "commandPostprocessorArgs": {"errorDetection": {"type": "CRC-16-CCIIT"}},
        }],
    }


def instance_config(station_port: int, frames: SdlsFrameLink | None = None, key_file: str = "") -> dict:
    """``etc/yamcs.taiji2.yaml``: archive services, the ground station link (and Yamcs's own SDLS frame link
    with ``frames``, its key at ``key_file`` relative to the data directory), the XTCE database, streams."""
    return {
        "services": [
            {"class": "org.yamcs.archive.XtceTmRecorder"},
            {"class": "org.yamcs.archive.ParameterRecorder"},
            {"class": "org.yamcs.archive.AlarmRecorder"},
            {"class": "org.yamcs.archive.EventRecorder"},
            {"class": "org.yamcs.archive.ReplayServer"},
            {"class": "org.yamcs.archive.CommandHistoryRecorder"},
            {"class": "org.yamcs.ProcessorCreatorService", "args": {"name": "realtime", "type": "realtime"}},
            {"class": "org.yamcs.parameterarchive.ParameterArchive", "args": {"realtimeFiller": {"enabled": True}}},
        ],
        "dataLinks": [{
            "name": LINK_NAME,
            "class": "org.yamcs.tctm.TcpTcTmDataLink",
            "tmStream": "tm_realtime",
            "tcStream": "tc_realtime",
            "host": "127.0.0.1",
            "port": int(station_port),
            "initialDelay": 0,
            "packetPreprocessorClassName": "org.yamcs.tctm.GenericPacketPreprocessor",
            "packetPreprocessorArgs": {
                "rootContainer": f"/{SYSTEM_NAME}/{ROOT_CONTAINER}",
                "timestampOffset": _CUC_OFFSET,
                "seqCountOffset": _SEQUENCE_NUMBER_OFFSET,
                "errorDetection": {"type": "CRC-16-CCIIT"},  # Yamcs's spelling
                "timeEncoding": {"type": "CUC", "epoch": "CUSTOM", "epochUTC": MISSION_EPOCH_UTC,
                                 "timeIncludesLeapSeconds": False},
            },
            # the telecommands' length, sequence count (per APID, into the command history as ccsds-seqcount,
            # which the verifiers match with the onboard reports) and CRC
            "commandPostprocessorClassName": "org.yamcs.pus.PusCommandPostprocessor",
            "commandPostprocessorArgs": {"errorDetection": {"type": "CRC-16-CCIIT"}},
        }, *([_frame_link(frames, key_file)] if frames else [])],
        "mdb": [{"type": "xtce", "args": {"file": "mdb/taiji2.xml"}}],
        "streamConfig": {
            "tm": [{"name": "tm_realtime", "processor": "realtime"}, {"name": "tm_dump"}],
            "cmdHist": ["cmdhist_realtime", "cmdhist_dump"],
            "event": ["events_realtime", "events_dump"],
            "param": ["pp_realtime", "pp_dump", "sys_param", "proc_param"],
            "parameterAlarm": ["alarms_realtime"],
            "tc": [{"name": "tc_realtime", "processor": "realtime"},
                   *([{"name": FRAME_STREAM, "processor": "realtime"}] if frames else [])],
        },
    }


def processor_config() -> dict:
    """``etc/processor.yaml`` (Yamcs requires it): the realtime processor and the archive's replays."""
    replay = {"services": [{"class": "org.yamcs.tctm.ReplayService"},
                           {"class": "org.yamcs.algorithms.AlgorithmManager"}]}
    return {
        "realtime": {
            "services": [
                {"class": "org.yamcs.StreamTmPacketProvider"},
                {"class": "org.yamcs.StreamTcCommandReleaser"},
                {"class": "org.yamcs.tctm.StreamParameterProvider", "args": {"streams": ["pp_realtime", "sys_param"]}},
                {"class": "org.yamcs.algorithms.AlgorithmManager"},
                {"class": "org.yamcs.parameter.LocalParameterManager"},
            ],
            "config": {
                "subscribeAll": True,
                "persistParameters": True,
                "alarm": {"parameterCheck": True, "parameterServer": "enabled"},
                "tmProcessor": {"ignoreOutOfContainerEntries": False},
                "recordLocalValues": True,
            },
        },
        "Archive": replay,
        "ParameterArchive": replay,
        "ArchiveRetrieval": {**replay, "config": {"subscribeContainerArchivePartitions": False}},
    }


def write_instance(data_dir: str | Path, *, http_port: int, station_port: int,
                   frames: SdlsFrameLink | None = None) -> Path:
    """Write the configuration, the XTCE database and the security configuration (authentication on, the
    operator's and the observer's credentials made once: :mod:`.yamcs_security`) into ``data_dir`` (created
    if missing; the archive and the credentials in it are kept) and return its ``etc`` directory."""
    root = Path(data_dir).resolve()
    etc = root / "etc"
    etc.mkdir(parents=True, exist_ok=True)
    (root / "mdb").mkdir(exist_ok=True)
    write_xtce(root / "mdb" / "taiji2.xml")
    key_file = ""
    if frames is not None:
        key_file = f"etc/sdls-spi{int(frames.spi)}.key"
        descriptor = os.open(root / key_file, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(descriptor, "wb") as f:
            f.write(frames.key)
    for name, config in (("yamcs.yaml", server_config(http_port)),
                         (f"yamcs.{INSTANCE}.yaml", instance_config(station_port, frames, key_file)),
                         ("processor.yaml", processor_config())):
        (etc / name).write_text(yaml.safe_dump(config, sort_keys=False))
    write_security(root)
    return etc
