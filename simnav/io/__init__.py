"""Dataset and log I/O: TUM trajectories, CARMEN laser logs and the TUM RGB-D dataset layout.

Every writer is deterministic byte for byte (fixed float formatting, no wall-clock time in any file), so a
recording of the same simulation can be compared with ``cmp``. Readers raise :class:`DataFormatError` naming
the file, the line and what was expected, and :class:`MissingDataError` naming a file or folder that is not
there.
"""

from __future__ import annotations

import math
from pathlib import Path

from simnav.errors import SimnavError


class DataFormatError(SimnavError, ValueError):
    """A data file does not follow its format; the message names the file, the line and what was expected."""


class MissingDataError(SimnavError, FileNotFoundError):
    """A data file or folder that is required does not exist; the message names it."""

    def __str__(self) -> str:  # FileNotFoundError would format (errno, strerror) tuples
        return str(self.args[0]) if self.args else ""


def json_finite(value):
    """``value`` (nested dicts and lists) with every inf/nan float replaced by None: JSON has neither."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_finite(v) for v in value]
    return value


def format_error(path: str | Path, line_no: int | None, message: str) -> DataFormatError:
    """Builds a :class:`DataFormatError` reading ``"<path>:<line>: <message>"`` (line numbers start at 1)."""
    where = f"{path}:{line_no}" if line_no is not None else f"{path}"
    return DataFormatError(f"{where}: {message}")


# Submodules import the errors above, so they are imported after them.
from simnav.io.carmen import CarmenLog, CarmenWriter, OdomStream, TruePosStream, read_carmen  # noqa: E402
from simnav.io.rgbd_dataset import (  # noqa: E402
    TUM_FR1_K,
    RGBDDataset,
    RGBDDatasetWriter,
    load_pixel_motion,
    save_pixel_motion,
)
from simnav.io.tum import (  # noqa: E402
    Trajectory,
    TumWriter,
    read_tum,
    read_tum_covariance,
    sidecar_path,
    write_tum,
)

__all__ = [
    "TUM_FR1_K",
    "CarmenLog",
    "CarmenWriter",
    "DataFormatError",
    "MissingDataError",
    "OdomStream",
    "RGBDDataset",
    "RGBDDatasetWriter",
    "Trajectory",
    "TruePosStream",
    "TumWriter",
    "format_error",
    "json_finite",
    "load_pixel_motion",
    "read_carmen",
    "read_tum",
    "read_tum_covariance",
    "save_pixel_motion",
    "sidecar_path",
    "write_tum",
]
