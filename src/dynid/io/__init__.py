"""File formats: log readers (CSV, NPZ, Parquet) and staged output folders."""

from dynid.io.output import staged_output
from dynid.io.readers import TableReader, file_sha256

__all__ = ["TableReader", "file_sha256", "staged_output"]
