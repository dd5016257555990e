"""How much the held-out check protects against a fluctuation the selection took for an effect.

The diagnosis selects a variant on its gain over the whole run (delta chi2 >= the selection floor) and then
checks it on the held-out part (the last third by default): its magnitude trained on the rest, applied there,
``heldout_z`` against "no effect" (:mod:`taiji2_estimator_pkg.diagnosis.evaluation`). The held-out part is a
part of the run that selected it, so where there is no effect its z is not independent of the selection: a
fluctuation that cleared the floor over the whole run tends to be in the held-out part too.

This measures, in the Gaussian linear model of one variant (its whole-run projection the sum of the training
part's and the held-out part's, shares ``1 - f`` and ``f`` of its information), the chance that a selected
fluctuation passes z >= ``HELDOUT_Z_MIN`` and z >= ``HELDOUT_Z_STRONG``, for the floors the diagnosis uses
(:func:`taiji2_estimator_pkg.diagnosis.standing.unconfirmed_floor`), and the naming level that follows (naming
rule 2b: a weak effect needs the unconfirmed floor, unless its z reaches ``HELDOUT_Z_STRONG``), against the
0.159 x level the rule was designed for.

Usage::

    python benchmarks/bench_heldout_null.py [--draws 40000000] [--heldout-share 0.333] [--seed 1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2 as chi2_dist
from scipy.stats import norm

try:
    from taiji2_estimator_pkg.diagnosis import standing
except ImportError:  # editable install made before the package had modules
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src" / "taiji2_estimator_pkg"))
    from taiji2_estimator_pkg.diagnosis import standing

#: the selection floor for one parameter (delta chi2) with the default catalog (alpha 0.01 over 71 variants)
SELECTION_FLOOR = float(chi2_dist.isf(0.01 / 71, 1))


def selected_null_z(draws: int, heldout_share: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Whole-run gains and held-out z of ``draws`` noise-only runs of one variant (delta chi2 of one parameter).

    Returns
    -------
    gain : numpy.ndarray
        Whole-run delta chi2 (chi-square, 1 degree of freedom).
    z : numpy.ndarray
        Held-out z: the held-out projection, in its own sigmas, signed by the trained magnitude's sign.
    """
    train = rng.normal(0.0, np.sqrt(1.0 - heldout_share), draws)
    heldout = rng.normal(0.0, np.sqrt(heldout_share), draws)
    return (train + heldout) ** 2, np.sign(train) * heldout / np.sqrt(heldout_share)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=40_000_000)
    parser.add_argument("--heldout-share", type=float, default=1.0 / 3.0,
                        help="share of the variant's information in the held-out part (default 1/3)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    level = float(chi2_dist.sf(SELECTION_FLOOR, 1))
    unconfirmed = standing.unconfirmed_floor(level, 1)
    gain, z = selected_null_z(args.draws, args.heldout_share, np.random.default_rng(args.seed))
    selected = gain >= SELECTION_FLOOR
    below = selected & (gain < unconfirmed)
    pass_min = float(np.mean(z[selected] >= standing.HELDOUT_Z_MIN))
    pass_strong = float(np.mean(z[below] >= standing.HELDOUT_Z_STRONG))
    named = float(np.mean(gain >= unconfirmed) + np.mean(below & (z >= standing.HELDOUT_Z_STRONG)))
    print(f"held-out share {args.heldout_share:.3f}; {args.draws} noise-only runs (seed {args.seed}); "
          f"{int(selected.sum())} selected at delta chi2 >= {SELECTION_FLOOR:.2f} (level {level:.2e} per variant)")
    print(f"  P(z >= {standing.HELDOUT_Z_MIN:g} | selected)                 = {pass_min:.3f}"
          f"   (independent: {standing.HELDOUT_NULL_PASS:.3f})")
    print(f"  P(z >= {standing.HELDOUT_Z_STRONG:g} | selected, delta chi2 < {unconfirmed:.2f}) = {pass_strong:.3f}"
          f"   (independent: {float(norm.sf(standing.HELDOUT_Z_STRONG)):.4f})")
    print(f"  a weak effect named where there is none (rule 2b with the z >= {standing.HELDOUT_Z_STRONG:g} bypass): "
          f"{named / level:.3f} x level (rule 2b alone: {standing.HELDOUT_NULL_PASS:.3f} x level)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
