"""Metrics: per-stage tables written as parquet (pyarrow), aggregated per scene
and per dataset. A metric that cannot be computed is stored as null (missing),
never as a made-up number."""

from gs2e.metrics.table import read_metrics, write_metrics

__all__ = ["write_metrics", "read_metrics"]
