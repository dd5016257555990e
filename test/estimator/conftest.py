"""Fixtures of the estimator tests."""

from __future__ import annotations

import pytest

from estimator_support import simulate


@pytest.fixture(scope="session")
def sim():
    """The cached :func:`simulate`."""
    return simulate
