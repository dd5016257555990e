"""``taiji2 <verb> ...``: dispatches to the verbs registered in the ``taiji2.commands`` entry-point group.

Each verb module provides ``add_arguments(parser)`` and ``main(args) -> int``; packages add verbs
(``calibrate``, ``diagnose``, ``experiment``) by declaring an entry point, so this package needs
no knowledge of them.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from importlib.metadata import entry_points

from taiji2_runtime.entry import report_error

_BUILTIN_VERBS = {
    "run": "taiji2_runtime.cli.run",
    "topic": "taiji2_runtime.cli.topic",
    "bag": "taiji2_runtime.cli.bag",
}


def _verbs() -> dict[str, str]:
    verbs = dict(_BUILTIN_VERBS)
    for ep in entry_points(group="taiji2.commands"):
        verbs.setdefault(ep.name, ep.value)
    return verbs


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, str]]:
    import importlib

    parser = argparse.ArgumentParser(prog="taiji2", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="verb", metavar="<verb>")
    sub.required = True
    verbs = _verbs()
    for name, module_name in sorted(verbs.items()):
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue
        verb_parser = sub.add_parser(name, help=(module.__doc__ or "").strip().splitlines()[0],
                                     description=module.__doc__)
        module.add_arguments(verb_parser)
        verb_parser.set_defaults(_module=module)
    return parser, verbs


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser, _ = build_parser()
    # `taiji2 run pkg exe ...` passes everything after the executable to the node untouched
    if argv[:1] == ["run"]:
        from taiji2_runtime.cli import run

        return run.run_from_argv(argv[1:])
    args = parser.parse_args(argv)
    try:
        return int(args._module.main(args) or 0)
    except KeyboardInterrupt:
        return 130
    except (ValueError, LookupError, OSError, RuntimeError) as exc:
        report_error(f"taiji2 {args.verb}", exc)
        return 2


if __name__ == "__main__":
    sys.exit(main())
