"""The `taiji2` command imports a verb's dependencies only when that verb runs (no timing asserted)."""

from __future__ import annotations

import json
import subprocess

from support import PYTHON, python_subprocess_env

HEAVY = ("matplotlib", "scipy", "numpy", "cyclonedds", "rosbags", "yaml")

CHECK = """
import contextlib, io, json, sys
from taiji2_apps.cli.main import main, registered_verbs
argv = json.loads(sys.argv[1])
out = io.StringIO()
with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
    try:
        status = main(argv)
    except SystemExit as exc:
        status = exc.code
heavy = sorted({m.split('.')[0] for m in sys.modules} & set(json.loads(sys.argv[2])))
print(json.dumps({"status": status, "heavy": heavy, "chars": len(out.getvalue()),
                  "verbs": sorted(registered_verbs()), "text": out.getvalue()}))
"""


def _run(argv: list[str]) -> dict:
    proc = subprocess.run([PYTHON, "-c", CHECK, json.dumps(argv), json.dumps(HEAVY)], env=python_subprocess_env(),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_help_imports_no_verb_dependencies():
    result = _run(["--help"])
    assert result["status"] == 0
    assert result["heavy"] == [], f"taiji2 --help imported {result['heavy']}"
    # the help really lists the verbs (so the check is not vacuous)
    for verb in ("bag", "calibrate", "diagnose", "topic"):
        assert verb in result["verbs"]
        assert verb in result["text"]


def test_every_verb_help_imports_no_verb_dependencies():
    verbs = _run(["--help"])["verbs"]
    assert len(verbs) >= 5
    for verb in verbs:
        if verb == "run":  # `taiji2 run` hands its arguments to the executable
            continue
        result = _run([verb, "--help"])
        assert result["status"] == 0, verb
        assert result["chars"] > 50, verb
        assert result["heavy"] == [], f"taiji2 {verb} --help imported {result['heavy']}"


def test_unknown_verb_is_a_one_line_usage_error():
    proc = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "no-such-verb"], env=python_subprocess_env(),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "invalid choice" in proc.stderr and "Traceback" not in proc.stderr


def test_every_verb_is_a_cli_module_of_the_runtime_or_the_applications():
    """The verb table names modules by string (imported when the verb runs), which no import check can
    see: each is importable and is a CLI module of the runtime (ros2-style tools) or of the applications
    (the top layer), never of a lower package."""
    import importlib.util

    from taiji2_apps.cli.main import VERBS

    for verb, module in VERBS.items():
        assert module.startswith(("taiji2_runtime.cli.", "taiji2_apps.cli.")), (verb, module)
        assert importlib.util.find_spec(module) is not None, (verb, module)
