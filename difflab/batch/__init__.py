"""Batches of fits from a manifest: `fit_many` and `difflab fit-batch`, resumable, on this machine's
cores or a Dask cluster. Importing this package imports neither JAX nor Dask; the workers do."""

from .api import BatchSummary, fit_many
from .manifest import Invalid, Job, load_manifest

__all__ = ["BatchSummary", "Invalid", "Job", "fit_many", "load_manifest"]
