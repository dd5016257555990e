"""Time correlation: the ground's map from onboard (CUC) time to the contract's time.

``contract_time = offset_s + rate * onboard_time``, identity by default (offset 0, rate 1: the
onboard clock's zero is the contract's time zero). Given as a small YAML mapping (a file of its
own, or the ``time_correlation`` section of a layout / ``--config`` file)::

    time_correlation:
      offset_s: 1700000000.0   # contract time of onboard time zero [s]
      rate: 1.0000000012       # contract seconds per onboard second

Computed in integer nanoseconds (exact for the identity and any whole-ns offset with rate 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["TimeCorrelation", "load_time_correlation"]

_NS = 1_000_000_000


@dataclass(frozen=True)
class TimeCorrelation:
    """``contract = offset_s + rate * onboard``.

    Attributes
    ----------
    offset_s : float
        Contract time of onboard time zero [s].
    rate : float
        Contract seconds per onboard second (> 0).
    """

    offset_s: float = 0.0
    rate: float = 1.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.offset_s) and np.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"time correlation needs a finite offset_s and a rate > 0, got {self}")

    @property
    def offset_ns(self) -> int:
        """Offset [ns], rounded."""
        return round(self.offset_s * _NS)

    def to_contract_ns(self, onboard_ns: np.ndarray) -> np.ndarray:
        """Contract times [ns] of onboard times [ns] (int64)."""
        onboard = np.asarray(onboard_ns, dtype=np.int64)
        out = onboard + np.int64(self.offset_ns)
        if self.rate != 1.0:
            out = out + np.rint((self.rate - 1.0) * onboard.astype(np.float64)).astype(np.int64)
        return out

    def to_onboard_ns(self, contract_ns: np.ndarray) -> np.ndarray:
        """Onboard times [ns] of contract times [ns] (int64; the inverse of :meth:`to_contract_ns`)."""
        since = np.asarray(contract_ns, dtype=np.int64) - np.int64(self.offset_ns)
        if self.rate != 1.0:
            since = since - np.rint((1.0 - 1.0 / self.rate) * since.astype(np.float64)).astype(np.int64)
        return since

    def as_dict(self) -> dict[str, float]:
        """``{"offset_s": ..., "rate": ...}``."""
        return {"offset_s": float(self.offset_s), "rate": float(self.rate)}


def load_time_correlation(path: str | Path) -> TimeCorrelation:
    """Read a time correlation from YAML: a ``time_correlation`` section or the bare mapping.

    Raises
    ------
    ValueError
        One line naming the file and the problem.
    """
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read the time correlation ({exc})") from None
    if isinstance(data, dict) and "time_correlation" in data:
        data = data["time_correlation"]
    if data is None:
        return TimeCorrelation()
    if not isinstance(data, dict) or set(data) - {"offset_s", "rate"}:
        raise ValueError(f"{path}: time_correlation must be a mapping with offset_s and/or rate")
    try:
        return TimeCorrelation(float(data.get("offset_s", 0.0)), float(data.get("rate", 1.0)))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
