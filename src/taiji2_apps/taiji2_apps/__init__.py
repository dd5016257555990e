"""Taiji-2 applications, the top layer: the ``taiji2`` command and what composes the packages below it.

- :mod:`.cli`: the verbs (``experiment``, ``calibrate``, ``diagnose``, ``simulate``, ``plot``, ``design``,
  ``campaign``, and the runtime's ``run``, ``topic``, ``bag``, ``node``, ``param``)
- :mod:`.campaign`: Monte Carlo campaigns on Dask
- :mod:`.design`: maneuver design against the Cramer-Rao bound
- :mod:`.experiment_setup`: what an experiment flies, from the command line's choices
- :mod:`.runner`: the experiment runner (start, supervise, progress, stop) that ``taiji2 experiment`` runs its
  graph with, with and without ``--link``
"""
