"""Rays against line segments in the plane (pure numpy): synthetic 2D scans of known geometry."""

from __future__ import annotations

import numpy as np


def first_hits(segments: np.ndarray, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance along each ray to the first segment it hits.

    Args:
        segments: (M, 4) segments ``x0, y0, x1, y1``, m.
        origin: (2,) ray origin, m (same frame as the segments).
        directions: (N, 2) unit ray directions.

    Returns:
        (N,) distances, m (inf where nothing is hit).
    """
    p, e = segments[:, :2], segments[:, 2:] - segments[:, :2]
    d = directions[:, None, :]
    w = p[None, :, :] - origin[None, None, :]
    den = d[..., 0] * e[None, :, 1] - d[..., 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        s = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den
    hit = (np.abs(den) > 1e-12) & (t > 1e-9) & (s >= 0) & (s <= 1)
    return np.where(hit, t, np.inf).min(axis=1)
