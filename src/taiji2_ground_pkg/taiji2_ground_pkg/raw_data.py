"""Raw data as the ground holds it, whatever its form: a ROS 2 bag, CCSDS packet files, or the packets a Yamcs
instance archived (``yamcs://HOST:PORT/INSTANCE``).

Real mission data arrive as packets; recorded experiments as bags. :func:`load_raw_data` recognises the
form by content and returns the same arrays either way, so ``taiji2 calibrate`` and ``taiji2 diagnose``
read both.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from taiji2_estimator_pkg.io.raw_bag import RawBagError, RawExperiment, load_raw_bag
from taiji2_ground_pkg.raw_packets import load_raw_archive, load_raw_packets
from taiji2_model.contract import RAW_TOPICS
from taiji2_runtime.packets.files import is_packet_path

__all__ = ["load_raw_data"]


def load_raw_data(path: str | Path, *, required: Iterable[str] = tuple(RAW_TOPICS),
                  correlation: Any = None) -> RawExperiment:
    """Load the raw streams at ``path``: a bag (:func:`~taiji2_estimator_pkg.io.raw_bag.load_raw_bag`) or
    a CCSDS packet file or directory, recognised by content
    (:func:`~taiji2_ground_pkg.raw_packets.load_raw_packets`).

    Parameters
    ----------
    path : str or pathlib.Path
        Bag directory or file, packet file or directory, or a Yamcs address (``yamcs://...``).
    required : iterable of str
        Raw topics that must be present with usable messages (default: all four of the contract).
    correlation : taiji2_runtime.packets.time_correlation.TimeCorrelation, optional
        Packets only: onboard -> contract time (default: the directory's ``time_correlation.yaml``, else the
        identity).

    Raises
    ------
    taiji2_estimator_pkg.io.raw_bag.RawBagError
        (a ValueError) naming the file and the problem.
    """
    from taiji2_ground_pkg.mcs.yamcs_api import is_yamcs_url

    if is_yamcs_url(str(path)):
        return load_raw_archive(str(path), required=required, correlation=correlation)
    if is_packet_path(Path(path)):
        return load_raw_packets(path, required=required, correlation=correlation)
    try:
        return load_raw_bag(path, required=required)
    except RawBagError as exc:
        if not exc.problem.startswith("not a ROS 2 bag"):
            raise
        # neither form: say both, since a user with packets may not know they are read too
        either = "neither a ROS 2 bag nor CCSDS Space Packets (a packet file or directory, recognised by content)"
        raise RawBagError(exc.path, exc.problem.replace("not a ROS 2 bag", either, 1)) from None
