"""Accepted effects the data determine only jointly (partners), for the naming rule.

Two accepted effects whose fitted magnitudes correlate almost perfectly in the final joint fit
(``|rho| >= alias_correlation``) split one gap between them: e.g. a command-to-GRS group delay of
0.1 s fitted as a latency plus a thruster lag, whose sum is fixed to 0.5 ms but whose split only
to 20 ms. Each one's drop-one gain is then small (its partner takes the gap back when it is
dropped), so judged alone neither would "stand on its own" although together they close the
gap. The naming rule therefore judges an effect against the model without its partners: the
group stands or falls together, and the report lists the partners so that the split is read as
the poorly determined quantity it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["jointly_determined"]


def jointly_determined(columns: Sequence[Sequence[str]], keys: Sequence[str], current: Sequence[str],
                       cov: np.ndarray, threshold: float) -> dict[str, list[str]]:
    """Partners of each accepted effect: other accepted effects whose parameters correlate with its own.

    Parameters
    ----------
    columns : sequence of sequence of str
        Column names of each accepted (deterministic) effect.
    keys : sequence of str
        Their variant keys, in the same order.
    current : sequence of str
        Column names of the final model, in the order of ``cov``.
    cov : numpy.ndarray
        Covariance of the final joint fit.
    threshold : float
        Smallest ``|rho|`` between a parameter of one and a parameter of the other that makes them
        partners.

    Returns
    -------
    dict of str to list of str
        Key -> partner keys (only effects that have partners).
    """
    position = {name: i for i, name in enumerate(current)}
    sigma = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    out: dict[str, list[str]] = {}
    for a, (cols_a, key_a) in enumerate(zip(columns, keys, strict=True)):
        for b, (cols_b, key_b) in enumerate(zip(columns, keys, strict=True)):
            if a == b:
                continue
            rho = max((abs(cov[position[i], position[j]]) / (sigma[position[i]] * sigma[position[j]])
                       for i in cols_a for j in cols_b if sigma[position[i]] > 0 and sigma[position[j]] > 0),
                      default=0.0)
            if math.isfinite(rho) and rho >= threshold:
                out.setdefault(key_a, []).append(key_b)
    return out
