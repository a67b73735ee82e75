"""Metrics: per-stage tables written as parquet (pyarrow), aggregated per scene
and per dataset. A metric that cannot be computed is stored as null (missing),
never as a made-up number.

The package imports nothing (pandas is loaded where tables are written):
see :mod:`gs2e.metrics.table`.
"""
