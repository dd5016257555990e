"""Run an executable of a package, as ``ros2 run <package> <executable> [args]`` does."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, distribution


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("package", help="package name, e.g. taiji2_sim_pkg")
    parser.add_argument("executable", help="executable name, e.g. maneuver_commander")
    parser.add_argument("argv", nargs=argparse.REMAINDER, help="arguments passed to the executable (--ros-args ...)")


def executables(package: str) -> dict[str, object]:
    """``{name: entry point}`` of a package's console scripts.

    Raises
    ------
    LookupError
        If the package is not installed.
    """
    try:
        dist = distribution(package)
    except PackageNotFoundError:
        raise LookupError(f"package {package!r} not found") from None
    return {ep.name: ep for ep in dist.entry_points if ep.group == "console_scripts"}


def run_from_argv(argv: Sequence[str]) -> int:
    if len(argv) < 2 or argv[0].startswith("-"):
        print("usage: taiji2 run <package> <executable> [args ...]", file=sys.stderr)
        return 2
    package, executable, rest = argv[0], argv[1], list(argv[2:])
    try:
        table = executables(package)
    except LookupError as exc:
        print(f"error: taiji2 run: {exc}", file=sys.stderr)
        return 2
    if executable not in table:
        available = ", ".join(sorted(table)) or "none"
        print(f"error: taiji2 run: no executable {executable!r} in package {package!r} (available: {available})",
              file=sys.stderr)
        return 2
    sys.argv = [executable, *rest]
    main = table[executable].load()
    return int(main() or 0)


def main(args: argparse.Namespace) -> int:
    return run_from_argv([args.package, args.executable, *args.argv])
