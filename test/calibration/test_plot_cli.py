"""`taiji2 plot` writes the four paper-style figures as PNG."""

from __future__ import annotations

import subprocess

from support import PYTHON, python_subprocess_env

FIGURES = ("angular_acceleration_fit", "scale_factors_vs_time", "com_offsets_vs_time", "error_vs_crlb")


def test_plot_writes_png_figures(tmp_path):
    proc = subprocess.run([PYTHON, "-m", "taiji2_apps.cli.main", "plot", "--duration-s", "1200", "--out",
                           str(tmp_path)], env=python_subprocess_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    # what it does on stderr, only the files on stdout (the first-hour contract: a script can read the paths)
    for stage in ("simulating", "running the estimators", "drawing the figures", "done"):
        assert stage in proc.stderr
    assert all(line.endswith(".png") for line in proc.stdout.splitlines()) and proc.stdout.strip()
    for name in FIGURES:
        png = tmp_path / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000, name
