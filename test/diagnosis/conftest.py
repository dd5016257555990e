"""Fixtures of the diagnosis tests."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module", autouse=True)
def _unclipped_readout():
    """These tests study the paper's preset with every noise on, which leaves the GRS range: they keep the
    unclipped readout they were made for (the study switch grs.readout_saturation: false; test/support.py)."""
    from support import unclipped_readout_patch

    patch = unclipped_readout_patch()
    yield
    patch.undo()
