"""ROS 2 bags without ROS: record, play, inspect, and bulk-read (rosbags underneath).

=================  ==============================================================================
module             responsibility
=================  ==============================================================================
``errors``         :class:`BagError`, the one-line error of every bag tool
``contract``       topics and types of the raw-data contract
``reading``        open a bag (errors -> BagError), check / register its embedded definitions
``bulk_read``      stamps and raw CDR bytes of whole topics, without a per-message loop
``bulk_decode``    fixed-layout CDR messages -> numpy columns
``writer``         crash-safe rosbag2 writer (segments + short journal files, atomic metadata)
``runtime_adapter``  rclpy vs embedded runtime: raw bytes in and out, publishers' QoS
``provenance``     recorder / simulator provenance for the bag's custom data
``recorder``       :class:`Recorder`: live graph -> bag
``player``         :class:`Player`: bag -> live graph
``info``           :func:`bag_info`: summary of a bag
=================  ==============================================================================

``recorder``, ``player`` and ``runtime_adapter`` import the ROS client library; the other modules
do not, so offline tools can read bags without starting DDS.
"""

from __future__ import annotations

from typing import Any

from taiji2_runtime.bag.errors import BagError

__all__ = ["BagError", "BagSummary", "PlayOptions", "Player", "RecordOptions", "Recorder", "bag_info",
           "check_bag_path", "format_info", "open_reader"]

#: imported on first use: a tool imports only the modules it uses (and rosbags' readers only when it reads)
_LAZY = {"Recorder": "recorder", "RecordOptions": "recorder", "Player": "player", "PlayOptions": "player",
         "BagSummary": "info", "bag_info": "info", "format_info": "info", "check_bag_path": "reading",
         "open_reader": "reading"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(name)
