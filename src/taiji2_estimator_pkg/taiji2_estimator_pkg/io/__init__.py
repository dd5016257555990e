"""Input/output of the estimator package: loading recorded experiments for offline calibration."""

from .raw_bag import CommandData, GrsData, RawBagError, RawExperiment, StarTrackerData, TopicReport, load_raw_bag

__all__ = ["CommandData", "GrsData", "RawBagError", "RawExperiment", "StarTrackerData", "TopicReport",
           "load_raw_bag"]
