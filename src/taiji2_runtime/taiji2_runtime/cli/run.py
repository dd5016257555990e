"""Run an executable of a package, as ``ros2 run <package> <executable> [args]`` does."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, distribution

from taiji2_runtime.cli.plain_text import plain_text


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


_USAGE = "usage: taiji2 run [-h] <package> <executable> [args ...]"
_HELP = f"""{_USAGE}

{plain_text(__doc__.strip())}

positional arguments:
  package     package name, e.g. taiji2_sim_pkg (taiji2 run <package> lists its executables)
  executable  executable name, e.g. maneuver_commander
  args        passed to the executable unchanged: --ros-args -p name:=value, --params-file FILE,
              -r from:=to, --log-level LEVEL (taiji2 run <package> <executable> --help: the node's own)

options:
  -h, --help  show this help message and exit

example: taiji2 run taiji2_sim_pkg maneuver_commander --ros-args -p preset:=type2"""


def _list_executables(package: str, table: dict[str, object]) -> str:
    names = "\n".join(f"  {name}" for name in sorted(table)) or "  (none)"
    return f"executables of {package} (taiji2 run {package} <executable>):\n{names}"


def _node_help(package: str, executable: str, entry: object) -> str:
    """What ``taiji2 run <package> <executable> --help`` shows: the node's docstring and where its
    parameters are documented (nodes take --ros-args, not options of their own)."""
    import importlib
    from pathlib import Path

    module_name = getattr(entry, "value", "").partition(":")[0]
    try:
        doc = importlib.import_module(module_name).__doc__ or ""
    except ImportError:
        doc = ""
    lines = [f"usage: taiji2 run {package} {executable} [--ros-args -p name:=value ... | --params-file FILE "
             "| -r from:=to ... | --log-level LEVEL]", ""]
    if doc.strip():
        lines += [plain_text(doc.strip()), ""]
    import os
    import sys

    module = sys.modules.get(module_name)
    dirs = [Path(module.__file__).resolve().parents[2] / "config"] if module and module.__file__ else []
    prefixes = [sys.prefix, *os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)]
    dirs += [Path(p) / "share" / package / "config" for p in prefixes if p]
    found = next((d for d in dirs if d.is_dir()), None)
    where = f"share/{package}/config of the installation"
    if found is not None:
        own = found / f"{executable}.yaml"
        where = str(own) if own.is_file() else f"the YAML files in {found}"
    lines.append(f"parameters (meaning, unit, default): {where}; while it runs: taiji2 param list")
    return "\n".join(lines)


def run_from_argv(argv: Sequence[str]) -> int:
    if not argv:
        print(f"{_USAGE}\nerror: taiji2 run: the following arguments are required: package, executable "
              "(taiji2 run --help)", file=sys.stderr)
        return 2
    if argv[0] in ("-h", "--help"):
        print(_HELP)
        return 0
    if argv[0].startswith("-"):
        print(f"{_USAGE}\nerror: taiji2 run: unknown option {argv[0]!r} (the node's options go after <executable>)",
              file=sys.stderr)
        return 2
    package = argv[0]
    try:
        table = executables(package)
    except LookupError as exc:
        print(f"error: taiji2 run: {exc}", file=sys.stderr)
        return 2
    if len(argv) < 2 or argv[1] in ("-h", "--help"):
        print(_list_executables(package, table))
        return 0
    executable, rest = argv[1], list(argv[2:])
    node_args = rest[:rest.index("--ros-args")] if "--ros-args" in rest else rest
    if executable in table and ("-h" in node_args or "--help" in node_args):
        print(_node_help(package, executable, table[executable]))
        return 0
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
