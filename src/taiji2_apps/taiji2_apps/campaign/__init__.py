"""Monte Carlo campaigns: a spec expands to cases, each a pure function of its inputs run on Dask.

``spec`` (load and validate a campaign spec, expand it into cases), ``case`` (run one case: batch
simulation, offline estimators, CRLB, optional diagnosis -> rows), ``store`` (Parquet chunks with
provenance metadata, resume), ``engine`` (Dask submission, progress, fault tolerance), ``summary``
(per-parameter statistics with bootstrap intervals) and ``plots``. See ``docs/campaigns.md``.
Submodules are imported on use: this package imports nothing heavy.
"""
