"""Calibration maneuver design: the maneuver that meets every G and d requirement in the least time.

``evaluate``: CRLB / requirement of the 12 parameters, range, thrust and attitude usage of a
candidate; ``families``: parameterisations of the square, multisine and piecewise families;
``optimize``: the constrained search; ``report``: report.md/json and PNGs. CLI: ``taiji2 design``.
"""
