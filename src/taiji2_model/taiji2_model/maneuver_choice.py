"""What a run flies: the one ``--maneuver`` of every verb that simulates (experiment, simulate, plot).

``design`` is the layout's shipped design (``config/maneuvers/LAYOUT.yaml`` of :mod:`taiji2_model`, a
``taiji2 design`` result), ``paper`` the layout's square-wave preset (the paper's maneuver), anything else a
maneuver file. The default is the shipped design where the layout has one (not with a ``--config`` file,
whose own maneuver section is then flown), else the preset: the same default for every verb, so a
``simulate`` then ``calibrate`` judges the maneuver that ``experiment`` flies.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["MANEUVER_CHOICES", "MANEUVER_HELP", "ManeuverChoice", "choose_maneuver"]

#: ``--maneuver`` keywords (anything else is a maneuver file)
MANEUVER_CHOICES = ("design", "paper")
#: the help of ``--maneuver``, the same for every verb
MANEUVER_HELP = ("what is flown: design (default where the layout has one: its shipped taiji2 design, "
                 "config/maneuvers/LAYOUT.yaml), paper (the layout's square-wave preset, the paper's maneuver), "
                 "or a maneuver file (maneuver.yaml of taiji2 design)")


@dataclass(frozen=True)
class ManeuverChoice:
    """A resolved ``--maneuver``.

    Attributes
    ----------
    maneuver : object
        Any family of :mod:`taiji2_model.maneuver_families` (the preset as a square wave).
    kind : str
        ``design``, ``paper`` or ``file``.
    file : str or None
        Absolute path of the maneuver file (None: the preset).
    label : str
        What is flown, in words (tables, plot titles, reports, bag provenance).
    duration_s : float
        The run's duration [s]: the one asked for, else the maneuver's end.
    """

    maneuver: Any
    kind: str
    file: str | None
    label: str
    duration_s: float

    def provenance(self) -> dict[str, Any]:
        """The choice as plain data (results, bag provenance): kind, file, label and the maneuver's parameters."""
        from taiji2_model.maneuver_families import maneuver_spec

        return {"kind": self.kind, "file": self.file, "label": self.label, **maneuver_spec(self.maneuver)}


def choose_maneuver(layout: str, choice: str | None, duration_s: float | None, *, config_file: str = "",
                    preset: Any = None) -> ManeuverChoice:
    """Resolve ``--maneuver`` for ``--layout`` (ValueError with a one-line message for a bad choice).

    Parameters
    ----------
    layout : str
        Built-in layout name (whose shipped design and preset are meant).
    choice : str or None
        ``design``, ``paper``, a maneuver file, or None for the default.
    duration_s : float or None
        The run's duration [s]; None: the maneuver's end.
    config_file : str
        A ``--config`` file: the default is then its own preset, not the layout's design.
    preset : SimConfig, optional
        The configuration whose maneuver section is the preset (default: the layout's).
    """
    from taiji2_model.config import ConfigError, load_config
    from taiji2_model.maneuver import ManeuverError, SquareWaveManeuver
    from taiji2_model.maneuver_families import builtin_maneuver_file, load_maneuver_file

    if choice is None:
        choice = "design" if not config_file and builtin_maneuver_file(layout) else "paper"
    if choice == "design":
        path = builtin_maneuver_file(layout)
        if path is None:
            raise ValueError(f"--maneuver design: no shipped design for layout {layout!r}; fly --maneuver paper, or "
                             f"make one with taiji2 design --layout {layout} --out DIR and pass DIR/maneuver.yaml")
        kind, label = "design", f"the shipped {layout} design (taiji2 design)"
    elif choice == "paper":
        path, kind, label = None, "paper", f"the paper's {layout} preset"
    else:
        path, kind, label = str(Path(choice).resolve()), "file", f"maneuver file {choice}"
    try:
        flown = load_maneuver_file(path) if path else None
        if flown is None and preset is None:
            preset = load_config(config_file or layout)
    except (ConfigError, ManeuverError) as exc:
        raise ValueError(str(exc)) from None
    if duration_s is None:  # the maneuver's end: the file's, or the preset's own (3 h for the built-in layouts)
        ending = flown if flown is not None else preset.maneuver
        duration_s = float(ending.start_s + ending.duration_s)
    if flown is None:
        m = preset.maneuver
        flown = SquareWaveManeuver(m.period_s, m.amplitude_n_m, m.phase_s, m.start_s, duration_s)
    return ManeuverChoice(flown, kind, path, label, float(duration_s))
