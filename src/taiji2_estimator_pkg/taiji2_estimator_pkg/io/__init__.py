"""Input/output of the estimator package: loading recorded experiments for offline calibration."""

from taiji2_estimator_pkg.io.raw_bag import (
           CommandData,
           GrsData,
           RawBagError,
           RawExperiment,
           StarTrackerData,
           TopicReport,
           load_raw_bag,
)

__all__ = ["CommandData", "GrsData", "RawBagError", "RawExperiment", "StarTrackerData", "TopicReport",
           "load_raw_bag"]
