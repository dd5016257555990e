"""``taiji2 <verb> ...``: ros2-style verbs that work with or without ROS 2 (the top of the layers).

Verbs are found by name, and a verb's module is imported only when that verb runs (or when its
help is shown), so ``taiji2 --help`` and a light verb start at once:

* this project's verbs are the table ``VERBS`` below (name -> module): the runtime's ros2-style tools
  (``run``, ``topic``, ``bag``, ``node``, ``param``) and the applications (``experiment``, ``calibrate``,
  ...); this package sits above every other, so it may name any of them;
* other packages add verbs by declaring an entry point in the ``taiji2.commands`` group
  (``"mine = my_pkg.cli.mine"`` in their ``setup.py``); the entry points are read only when the verb is
  not in the table, or for ``--help``.

A verb module provides ``add_arguments(parser)`` and ``main(args) -> int``, and imports only the
standard library at module level: what the verb uses (numpy, scipy, matplotlib, the DDS runtime,
rosbags) is imported inside ``main`` (a test checks this for every registered verb).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import NoReturn

from taiji2_apps.cli.exit_status import ExitStatus
from taiji2_runtime.cli.plain_text import plain_text

#: this project's verbs: name -> module (imported when the verb runs)
VERBS = {
    "run": "taiji2_runtime.cli.run",
    "topic": "taiji2_runtime.cli.topic",
    "bag": "taiji2_runtime.cli.bag",
    "node": "taiji2_runtime.cli.node",
    "param": "taiji2_runtime.cli.param",
    "calibrate": "taiji2_apps.cli.calibrate",
    "campaign": "taiji2_apps.cli.campaign",
    "design": "taiji2_apps.cli.design",
    "diagnose": "taiji2_apps.cli.diagnose",
    "experiment": "taiji2_apps.cli.experiment",
    "ground": "taiji2_apps.cli.ground",
    "plot": "taiji2_apps.cli.plot",
    "simulate": "taiji2_apps.cli.simulate",
}

_PROG = "taiji2"
_DESCRIPTION = "ros2-style verbs that work with or without ROS 2"


def registered_verbs() -> dict[str, str]:
    """Every verb: the project's table plus the ``taiji2.commands`` entry points (name -> module)."""
    from importlib.metadata import entry_points

    verbs = dict(VERBS)
    for ep in entry_points(group="taiji2.commands"):
        verbs.setdefault(ep.name, ep.value)
    return verbs


def _module_of(verb: str) -> str | None:
    return VERBS[verb] if verb in VERBS else registered_verbs().get(verb)


def _summary(module: ModuleType) -> str:
    return plain_text(module.__doc__.strip().splitlines()[0]) if module.__doc__ else ""


def _description(module: ModuleType) -> str | None:
    """The verb module's docstring without reStructuredText markup (the help a terminal shows)."""
    return plain_text(module.__doc__) if module.__doc__ else None


class _OneLineErrorParser(argparse.ArgumentParser):
    """argparse with the project's one-line errors: ``error: taiji2 <verb>: <problem> (see ... --help)``, status 2.

    argparse's own form prints the whole usage before ``<prog>: error: ...``, which buries the problem; the
    usage is one ``--help`` away. Sub-parsers (the verbs) are made of this class too."""

    def error(self, message: str) -> NoReturn:
        self.exit(ExitStatus.BAD_INPUT, f"error: {self.prog}: {message} (see {self.prog} --help)\n")


def _top_parser(verbs: dict[str, str]) -> tuple[argparse.ArgumentParser, argparse._SubParsersAction]:
    parser = _OneLineErrorParser(prog=_PROG, description=_DESCRIPTION)
    parser.add_argument(PRINT_CONFIG, action="store_true",
                        help="print the Cyclone DDS configuration of the embedded runtime (CYCLONEDDS_URI if set, "
                             "else the loopback default) on one line and exit; a mixed graph shares it: "
                             'export CYCLONEDDS_URI="$(taiji2 --print-cyclonedds-config)"')
    sub = parser.add_subparsers(dest="verb", metavar="<verb>", title="verbs")
    sub.required = True
    return parser, sub


def build_parser(verbs: dict[str, str] | None = None) -> argparse.ArgumentParser:
    """The full parser (every verb's module is imported for its arguments; for ``--help``)."""
    verbs = registered_verbs() if verbs is None else verbs
    parser, sub = _top_parser(verbs)
    for name, module_name in sorted(verbs.items()):
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue
        verb_parser = sub.add_parser(name, help=_summary(module), description=_description(module),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(verb_parser)
        verb_parser.set_defaults(_module=module)
    return parser


def _verb_parser(verb: str, module: ModuleType) -> argparse.ArgumentParser:
    """A parser that knows only ``verb`` (the others are not imported)."""
    parser, sub = _top_parser({verb: module.__name__})
    verb_parser = sub.add_parser(verb, help=_summary(module), description=_description(module),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    module.add_arguments(verb_parser)
    verb_parser.set_defaults(_module=module, _parser=verb_parser)
    return parser


def _report_error(where: str, exc: BaseException) -> None:
    from taiji2_runtime.entry import report_error

    report_error(where, exc)


#: verbs that run until stopped (nodes, recorder, echo): SIGINT is how a user ends them
_SERVICES = (("run",), ("bag", "record"), ("topic", "echo"))


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        return _main(argv)
    except KeyboardInterrupt:
        # Ctrl-C while the verb was still importing or starting, before its own SIGINT handling: a node or
        # recorder that had not started has nothing to flush and stops as cleanly as a running one (0);
        # a batch verb was cut short (130, the shell's code for SIGINT)
        return 0 if any(tuple(argv[: len(s)]) == s for s in _SERVICES) else 130


#: the top-level option that prints the Cyclone DDS configuration (no verb)
PRINT_CONFIG = "--print-cyclonedds-config"


def _main(argv: list[str]) -> int:
    if argv == [PRINT_CONFIG]:
        from taiji2_runtime.cyclonedds_config import effective_cyclonedds_config

        print(effective_cyclonedds_config())
        return 0
    verb = argv[0] if argv else ""
    module_name = _module_of(verb) if verb and not verb.startswith("-") else None
    if module_name is None:
        # no verb, an option (--help) or an unknown verb: the full parser reports it
        build_parser().parse_args(argv)
        return ExitStatus.BAD_INPUT
    # `taiji2 run pkg exe ...` passes everything after the executable to the node untouched
    if verb == "run":
        from taiji2_runtime.cli import run

        return run.run_from_argv(argv[1:])
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        print(f"{_PROG}: error: verb {verb!r} is registered ({module_name}) but cannot be imported: {exc}",
              file=sys.stderr)
        return ExitStatus.BAD_INPUT
    args, unknown = _verb_parser(verb, module).parse_known_args(argv)
    if unknown:  # said by the verb's parser, which names the verb
        args._parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return int(args._module.main(args) or 0)
    except BrokenPipeError:
        # whoever read stdout stopped (taiji2 bag info BAG | head): nothing went wrong in the verb
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        return 0
    except (ValueError, LookupError, OSError, RuntimeError) as exc:
        _report_error(f"{_PROG} {args.verb}", exc)
        return ExitStatus.BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
