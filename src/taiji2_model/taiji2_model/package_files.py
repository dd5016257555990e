"""Where a workspace package's ``config/`` folder is: in the source tree, or installed by pip or colcon.

Every package of the workspace ships its YAML files (layouts, maneuvers, node parameters, link models)
under ``config/`` in the source tree and under ``share/<package>/config`` once installed; this is the one
search for them.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["config_dirs"]


def config_dirs(package: str) -> list[Path]:
    """Candidate ``config`` directories of ``package``, most specific first (they need not exist).

    The source tree (``src/<package>/config`` beside this package's folder), then
    ``share/<package>/config`` under every parent of this file (a pip install into a prefix), under
    ``sys.prefix`` and under each entry of ``AMENT_PREFIX_PATH`` (a colcon install).
    """
    here = Path(__file__).resolve()
    dirs = [here.parents[2] / package / "config"]
    dirs += [parent / "share" / package / "config" for parent in here.parents]
    prefixes = [sys.prefix, *os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)]
    dirs += [Path(p) / "share" / package / "config" for p in prefixes if p]
    return dirs
