"""The ground segment on a mission control system: ``taiji2 ground xtce OUT.xml`` writes the XTCE database;
``taiji2 ground serve --data-dir DIR`` runs the ground station's Yamcs.

``xtce OUT.xml`` writes the packet definition (docs/interfaces.md, *CCSDS Space Packets*) as an XTCE 1.2
database (CCSDS 660.0), generated with yamcs-pymdb from the one packet definition in
``taiji2_runtime.packets.definition``: every telemetry APID and the PUS-C telecommands, for Yamcs or
any XTCE reader (docs/link.md, *The packets in a mission control system*).

``serve --data-dir DIR`` starts a Yamcs server with the project's instance configuration
(:mod:`taiji2_ground_pkg.mcs.yamcs_instance`) on ``DIR`` (its archive kept across restarts), prints the
instance's address (``yamcs://127.0.0.1:PORT/taiji2``) on stdout once the instance runs, and stops
Yamcs cleanly on Ctrl-C or SIGTERM (docs/operations.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from taiji2_apps.cli.exit_status import ExitStatus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="ground_verb", metavar="<xtce|serve>")
    sub.required = True
    xtce = sub.add_parser("xtce", help="write the XTCE database of the packets (CCSDS 660.0, XTCE 1.2)",
                          description="Write the packet definition as an XTCE 1.2 database, generated with "
                                      "yamcs-pymdb from taiji2_runtime.packets.definition.")
    xtce.add_argument("out", metavar="OUT.xml", help="the XTCE file to write (its directory must exist)")
    xtce.add_argument("--force", action="store_true", help="replace OUT.xml if it exists")
    serve = sub.add_parser("serve", help="run the ground station's Yamcs on a data directory until stopped",
                           description="Start Yamcs with the project's instance (the XTCE database, the ground "
                                       "station link, the archive) on DIR; print its address once ready; stop "
                                       "cleanly on Ctrl-C or SIGTERM.")
    serve.add_argument("--data-dir", required=True, metavar="DIR",
                       help="the instance's configuration (rewritten at start) and archive (kept); created if missing")
    serve.add_argument("--http-port", type=int, default=8090, metavar="PORT",
                       help="the HTTP API and web interface on 127.0.0.1 (default 8090)")
    serve.add_argument("--station-port", type=int, default=10015, metavar="PORT",
                       help="where the ground station front end listens for Yamcs's data link, on 127.0.0.1 "
                            "(default 10015; experiment --ground finds it through the API)")
    serve.add_argument("--ready-timeout-s", type=float, default=180.0, metavar="S",
                       help="give up if the instance is not running after this long (default 180)")
    serve.add_argument("--sdls-key-file", default="", metavar="KEYS",
                       help="Yamcs signs the telecommands itself as SDLS-secured TC frames (its UdpTcFrameLink, "
                            "AES-256-GCM authenticated encryption) with this key file's SPI, whose service must be "
                            "authenticated_encryption (docs/security.md); experiment --ground then uplinks Yamcs's "
                            "frames. Without it the ground station node signs")
    serve.add_argument("--sdls-spi", type=int, default=-1, metavar="N",
                       help="the SPI Yamcs signs with (default: the key file's highest active SPI)")
    serve.add_argument("--frame-port", type=int, default=-1, metavar="PORT",
                       help="where Yamcs sends its frames (UDP, 127.0.0.1; default the station port + 1, where "
                            "experiment --ground listens)")


def _check_output(out: Path, force: bool) -> str | None:
    """Why ``out`` cannot be written (None when it can)."""
    if out.is_dir():
        return f"{out}: is a directory; give a file name, e.g. {out / 'taiji2.xml'}"
    if not out.parent.is_dir():
        return f"{out}: directory {out.parent} does not exist"
    if out.exists() and not force:
        return f"{out}: already exists; choose another output or pass --force"
    return None


def main(args: argparse.Namespace) -> int:
    if args.ground_verb == "serve":
        return _serve(args)
    return _xtce(args)


def _serve(args: argparse.Namespace) -> int:
    import signal
    import sys

    from taiji2_ground_pkg.mcs.errors import GroundError
    from taiji2_ground_pkg.mcs.yamcs_server import YamcsServer

    for name in ("http_port", "station_port"):
        port = getattr(args, name)
        if not 1 <= port <= 65535:
            print(f"error: taiji2 ground serve: --{name.replace('_', '-')} {port}: not a TCP port (1-65535)",
                  file=sys.stderr)
            return ExitStatus.BAD_INPUT
    data_dir = Path(args.data_dir)
    if data_dir.exists() and not data_dir.is_dir():
        print(f"error: taiji2 ground serve: --data-dir {data_dir}: not a directory", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    frames, problem = _frame_link(args)
    if problem:
        print(f"error: taiji2 ground serve: {problem}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    server = YamcsServer(data_dir, http_port=args.http_port, station_port=args.station_port, frames=frames)
    stop = {"requested": False}

    def request_stop(signum: int, _frame: object) -> None:
        stop["requested"] = True
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, request_stop)
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
        server.start()
        print(f"ground: starting Yamcs on {data_dir} (log {server.log_path})", file=sys.stderr)
        waited = server.wait_ready(args.ready_timeout_s)
        print(f"ground: Yamcs ready in {waited:.1f} s; web interface http://127.0.0.1:{args.http_port}/, "
              f"ground station link on port {args.station_port}; Ctrl-C stops it", file=sys.stderr)
        if frames is not None:
            print(f"ground: Yamcs signs telecommands as SDLS frames (SPI {frames.spi}) sent to UDP port "
                  f"{frames.port}", file=sys.stderr)
        print(f"ground: authentication on; credentials (mode 0600): operator {server.credentials_file('operator')}, "
              f"observer {server.credentials_file('observer')}; clients read them through YAMCS_CREDENTIALS_FILE",
              file=sys.stderr)
        print(server.url, flush=True)
        server.process.wait()
        print(f"error: taiji2 ground serve: Yamcs exited by itself (status {server.process.returncode}); "
              f"see {server.log_path}", file=sys.stderr)
        return ExitStatus.FAILED
    except GroundError as exc:
        print(f"error: taiji2 ground serve: {exc}", file=sys.stderr)
        return ExitStatus.FAILED
    except KeyboardInterrupt:
        status = server.stop()
        print(f"ground: Yamcs stopped (status {status})", file=sys.stderr)
        return ExitStatus.OK
    except OSError as exc:
        print(f"error: taiji2 ground serve: {data_dir}: {exc.strerror or exc}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    finally:
        server.stop()


def _frame_link(args: argparse.Namespace) -> tuple[object | None, str]:
    """Yamcs's own SDLS frame link of ``--sdls-key-file`` (None without it), or why not (one line)."""
    if not args.sdls_key_file:
        return None, ""
    from taiji2_ground_pkg.mcs.yamcs_instance import SdlsFrameLink
    from taiji2_runtime.packets.sdls_keys import ACTIVE, AUTHENTICATED_ENCRYPTION, KeyFileError, load_key_file

    port = args.station_port + 1 if args.frame_port < 0 else args.frame_port
    if not 1 <= port <= 65535:
        return None, f"--frame-port {port}: not a UDP port (1-65535)"
    try:
        keys = load_key_file(args.sdls_key_file)
        sa = keys.newest_active() if args.sdls_spi < 0 else keys.get(args.sdls_spi)
    except (KeyFileError, ValueError) as exc:
        return None, f"--sdls-key-file {exc}"
    if sa is None or sa.state != ACTIVE:
        return None, f"--sdls-spi {args.sdls_spi}: not an active SPI of {args.sdls_key_file}"
    if sa.service != AUTHENTICATED_ENCRYPTION:
        return None, (f"--sdls-key-file {args.sdls_key_file}: SPI {sa.spi} is of service {sa.service}; Yamcs signs "
                      f"with {AUTHENTICATED_ENCRYPTION} only (set \"service\" of that key)")
    return SdlsFrameLink(key=sa.key, spi=sa.spi, port=port), ""


def _xtce(args: argparse.Namespace) -> int:
    import sys

    out = Path(args.out)
    problem = _check_output(out, args.force)
    if problem is not None:
        print(f"error: taiji2 ground: {problem}", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    from taiji2_ground_pkg.mcs.xtce import write_xtce

    try:
        write_xtce(out)
    except OSError as exc:
        print(f"error: taiji2 ground: {out}: cannot write ({exc.strerror or exc})", file=sys.stderr)
        return ExitStatus.BAD_INPUT
    print(out)
    return ExitStatus.OK
