"""Which calibration a user should take home from a diagnosis, and why (report section "Which calibration").

The diagnosis fits the GRS readout to the *commanded torque over the nominal inertia* (its nominal
calibration, docs/diagnosis.md): that calibration trusts the spacecraft inertia and the thruster torque
model, and its sigma is small because it takes them as exact. It is the reference against which the
diagnosis finds gaps. ``taiji2 calibrate`` (the star-tracker method, docs/estimators.md) estimates G from the
rotation the star tracker measures and d with that G: it uses neither the torque nor the inertia. So the
calibration to use is ``calibrate``'s; the torque-channel one beside it is a consistency check, and a
difference of more than a few combined sigma says the torque model (inertia, thruster gain) or a named
effect biases the torque channel.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["CONSISTENT_SIGMA", "calibration_choice"]

#: differences beyond this many combined sigma are named as a bias of the torque channel
CONSISTENT_SIGMA = 3.0
_G = ("G_phi", "G_theta", "G_psi")


def calibration_choice(star_tracker: Any, torque_channel: dict[str, Any], corrected: dict[str, Any] | None = None,
                       verdict: dict[str, Any] | None = None, blind_spots: list[dict[str, Any]] | None = None
                       ) -> dict[str, Any]:
    """The calibrations side by side, the one to use and why.

    Parameters
    ----------
    star_tracker : EstimateTable
        ``taiji2 calibrate``'s result on the same data (:func:`taiji2_estimator_pkg.calibration.calibrate`).
    torque_channel : dict
        The diagnosis's nominal calibration (``DiagnosisResult.calibration``: ``g_angular``,
        ``g_angular_sigma_relative``, ``com_offset_m``, ``com_offset_sigma_m``).
    corrected : dict, optional
        The diagnosis's corrected calibration (``DiagnosisResult.corrected``: the torque channel under the
        model extended with the named effects), added to the rows with its caveats.
    verdict : dict, optional
        The diagnosis's verdict (named effects, unexplained).
    blind_spots : list of dict, optional
        The diagnosis's blind spots (``DiagnosisResult.blind_spots``): those of more than
        :data:`CONSISTENT_SIGMA` become a caveat of the torque-channel and corrected calibrations.

    Returns
    -------
    dict
        ``use`` (``"calibrate"``, or ``"calibrate --config"`` where effects are named), ``why``, ``rows`` (per
        GRS and parameter: the values and sigmas and the difference in combined sigma), ``caveats`` of the
        corrected calibration and ``max_difference_sigma``.
    """
    rows = []
    for index, result in enumerate(star_tracker.grs):
        g = np.asarray(result.scale_factors, dtype=float)
        g_sigma = np.sqrt(np.diag(result.scale_factors_cov))
        d = np.asarray(result.com_offset_m, dtype=float)
        d_sigma = np.sqrt(np.diag(result.com_offset_cov))
        t_g = np.asarray(torque_channel["g_angular"][index], dtype=float)
        t_g_sigma = np.asarray(torque_channel["g_angular_sigma_relative"][index], dtype=float) * np.abs(t_g)
        t_d = np.asarray(torque_channel["com_offset_m"][index], dtype=float)
        t_d_sigma = np.asarray(torque_channel["com_offset_sigma_m"][index], dtype=float)
        c_g = c_g_sigma = c_d = c_d_sigma = np.full(3, np.nan)
        if corrected:
            c_g = np.asarray(corrected["g_angular"][index], dtype=float)
            c_g_sigma = np.asarray(corrected["g_angular_sigma_relative"][index], dtype=float) * np.abs(c_g)
            c_d = np.asarray(corrected["com_offset_m"][index], dtype=float)
            c_d_sigma = np.asarray(corrected["com_offset_sigma_m"][index], dtype=float)
        for names, ours, our_sigma, theirs, their_sigma, fixed, fixed_sigma in (
                (_G, g, g_sigma, t_g, t_g_sigma, c_g, c_g_sigma),
                (("d_x", "d_y", "d_z"), d, d_sigma, t_d, t_d_sigma, c_d, c_d_sigma)):
            for k, name in enumerate(names):
                combined = float(np.hypot(our_sigma[k], their_sigma[k]))
                rows.append({"grs": result.grs_id, "parameter": name, "calibrate": float(ours[k]),
                             "calibrate_sigma": float(our_sigma[k]), "torque_channel": float(theirs[k]),
                             "torque_channel_sigma": float(their_sigma[k]),
                             "difference_sigma": float((theirs[k] - ours[k]) / combined) if combined > 0 else None,
                             "corrected": None if np.isnan(fixed[k]) else float(fixed[k]),
                             "corrected_sigma": None if np.isnan(fixed_sigma[k]) else float(fixed_sigma[k])})
    differences = [abs(r["difference_sigma"]) for r in rows if r["difference_sigma"] is not None
                   and np.isfinite(r["difference_sigma"])]
    largest = max(differences, default=float("nan"))
    why = ("taiji2 calibrate estimates G from the rotation the star tracker measures and d with that G: it uses "
           "neither the commanded torque nor the spacecraft inertia. The diagnosis's nominal calibration fits the "
           "readout to the commanded torque over the nominal inertia: it trusts the inertia and the thruster torque "
           "model (its sigma takes them as exact), and serves as the reference against which gaps are found.")
    if np.isfinite(largest) and largest > CONSISTENT_SIGMA:
        why += (f" Here the two differ by up to {largest:.1f} combined sigma: the torque model (inertia, thruster "
                "gain) or an effect named in this report biases the torque channel.")
    elif np.isfinite(largest):
        why += f" Here they agree within {largest:.1f} combined sigma."
    use, caveats = "calibrate", []
    named = [name for name in (verdict or {}).get("effects", []) if name != "impulse"]
    if corrected:
        caveats.append("the corrected calibration is the torque channel's under the model extended with the named "
                       "effects (" + (", ".join(named) or "impulses only") + "): it trusts the nominal inertia too")
        if corrected.get("alias_uncertain"):
            caveats.append("left uncertain by an alias or a rival of a named effect (the corrected value is the "
                           "middle of their range, its sigma carries half of it): "
                           + ", ".join(corrected["alias_uncertain"]))
        if (verdict or {}).get("unexplained"):
            caveats.append("a gap remains unexplained: no correction covers it")
    unseen = [spot for spot in blind_spots or [] if spot["bias_sigma"] > CONSISTENT_SIGMA]
    if unseen:
        caveats.append("effects too small to be named here could still move the torque-channel calibration (and the "
                       "corrected one) by more than " + f"{CONSISTENT_SIGMA:g} sigma: " + ", ".join(
                           f"{spot['family']} up to {spot['bias_sigma']:.0f} sigma on {spot['parameter']}"
                           for spot in unseen[:4]) + " (section Blind spots)")
    if named and not (verdict or {}).get("unexplained"):
        use = "calibrate --config"
        why += (" Effects are named here: take taiji2 calibrate BAG --config FILE, FILE written by taiji2 diagnose "
                "BAG --write-config FILE (the star-tracker method with the named effects removed from the data); "
                "the corrected calibration beside it is its check.")
    return {"use": use, "why": why, "rows": rows, "caveats": caveats, "max_difference_sigma": largest}
