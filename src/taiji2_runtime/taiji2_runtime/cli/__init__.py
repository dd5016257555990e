"""The runtime's ros2-style verbs of the ``taiji2`` command (``run``, ``topic``, ``bag``, ``node``, ``param``);
the command itself is :mod:`taiji2_apps.cli.main`."""
