"""The ground segment on a mission control system: ``taiji2 ground xtce OUT.xml`` writes the XTCE database.

``xtce OUT.xml`` writes the packet definition (docs/interfaces.md, *CCSDS Space Packets*) as an XTCE 1.2
database (CCSDS 660.0), generated with yamcs-pymdb from the one packet definition in
``taiji2_runtime.packets.definition``: every telemetry APID and the PUS-C telecommands, for Yamcs or
any XTCE reader (docs/link.md, *The packets in a mission control system*).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from taiji2_apps.cli.exit_status import ExitStatus


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="ground_verb", metavar="<xtce>")
    sub.required = True
    xtce = sub.add_parser("xtce", help="write the XTCE database of the packets (CCSDS 660.0, XTCE 1.2)",
                          description="Write the packet definition as an XTCE 1.2 database, generated with "
                                      "yamcs-pymdb from taiji2_runtime.packets.definition.")
    xtce.add_argument("out", metavar="OUT.xml", help="the XTCE file to write (its directory must exist)")
    xtce.add_argument("--force", action="store_true", help="replace OUT.xml if it exists")


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
