"""Learned keyscan selection for SRF-Odometry (thesis §3.G.7): a working region in the translation-rotation plane.

The thesis models the alignment error of SRF as a function of the translation ``t`` and rotation ``r`` between
the two scans, learned in simulation per scanner, and takes a new keyscan when the motion since the current one
leaves the region where the error stays below 10 mm and 0.1 deg; it fits a fourth-degree polynomial to the
region's boundary. Here each simulated scan pair is labelled *good* when both errors are below those thresholds,
and the probability of a good alignment is a logistic model whose logit is a polynomial of degree 4 in ``t`` (m)
and ``|r|`` (rad)::

    P(good | t, r) = sigmoid(sum_k c_k t^i_k |r|^j_k)

The fit constrains the logit to be non-increasing in ``t`` and ``|r|`` on a fine grid over the sampled domain
(``[0, 1] m x [0, 1] rad``), so a motion smaller in both than one inside the region is inside too; motions
outside the domain count as outside the region.

Some failures do not depend on the motion (noise, a poor view): ``P(good | 0, 0)`` is below 1 and differs between
scanners. The working region is therefore relative to it: ``P(good | t, r) >= p_ratio * P(good | 0, 0)``, i.e.
the motion may cost at most a fraction ``1 - p_ratio`` of the alignments that would succeed without it.

The fitted models ship as JSON in ``keyscan_models/<preset>.json`` (see ``scripts/fit_keyscan_models.py``).

The working region is learned from random scan pairs, so it bounds the error of an *average* view. Where the
view changes abruptly (a doorway, a corner) a motion well inside it can leave the keyscan sharing little with
the new scan, and the keyscan alignment fails. :func:`keyscan_overlap` measures what the keyscan actually
observed of the new scan's view; :class:`simnav.odometry.srf.SRFOdometry` in mode KA drops a keyscan that
explains too little of it (``SRFConfig.keyscan_min_overlap``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from simnav.errors import ConfigError, UnknownNameError
from simnav.odometry.rangeflow import LevelGeometry, grid_index

MODEL_DIR = Path(__file__).resolve().parent / "keyscan_models"
"""Folder of the shipped models, one ``<preset>.json`` per 2D lidar preset."""
FORMAT = "simnav.keyscan_model/1"
"""Value of the ``format`` field of a model file."""
DEFAULT_EXPONENTS: tuple[tuple[int, int], ...] = tuple((i, d - i) for d in range(5) for i in range(d, -1, -1))
"""Monomials ``t^i |r|^j`` of the default model: every one of degree <= 4 (15; §3.G.7 fits a 4th-degree polynomial)."""
MONOTONE_GRID = 81
"""Points per axis of the grid over the sampled domain where the fit makes the logit non-increasing."""


# ----------------------------------------------------------------------------------------------------------------
# Model evaluation and fitting


def monomials(translation_m: np.ndarray, rotation_rad: np.ndarray,
              exponents: tuple[tuple[int, int], ...] = DEFAULT_EXPONENTS) -> np.ndarray:
    """Design matrix of the logistic model.

    Args:
        translation_m: (N,) translations, m (taken as absolute values).
        rotation_rad: (N,) rotations, rad (taken as absolute values).
        exponents: K pairs ``(i, j)`` for the features ``t^i |r|^j``.

    Returns:
        (N, K) features.
    """
    t = np.abs(np.asarray(translation_m, dtype=np.float64)).reshape(-1)
    r = np.abs(np.asarray(rotation_rad, dtype=np.float64)).reshape(-1)
    return np.stack([t**i * r**j for i, j in exponents], axis=1)


def monomial_gradients(translation_m: np.ndarray, rotation_rad: np.ndarray,
                       exponents: tuple[tuple[int, int], ...]) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of :func:`monomials` with respect to ``t`` and ``r`` at (N,) points ``t, r >= 0``; (N, K) each."""
    t = np.asarray(translation_m, dtype=np.float64).reshape(-1)
    r = np.asarray(rotation_rad, dtype=np.float64).reshape(-1)
    d_t = np.stack([i * t ** max(i - 1, 0) * r**j for i, j in exponents], axis=1)
    d_r = np.stack([j * t**i * r ** max(j - 1, 0) for i, j in exponents], axis=1)
    return d_t, d_r


def monotone_constraints(exponents: tuple[tuple[int, int], ...], max_translation_m: float,
                         max_rotation_rad: float, points: int = MONOTONE_GRID) -> np.ndarray:
    """Rows ``A`` such that ``A @ c <= 0`` makes the logit non-increasing in ``t`` and ``r`` on a grid.

    Returns:
        (2 points², K): d/dt and d/dr of the logit at every node of a ``points`` x ``points`` grid over
        ``[0, max_translation_m] x [0, max_rotation_rad]``.
    """
    t, r = np.meshgrid(np.linspace(0, max_translation_m, points), np.linspace(0, max_rotation_rad, points))
    d_t, d_r = monomial_gradients(t.ravel(), r.ravel(), exponents)
    return np.vstack([d_t, d_r])


def sigmoid(z: np.ndarray) -> np.ndarray:
    """Logistic function, stable for large ``|z|``."""
    return np.exp(-np.logaddexp(0.0, -z))


class _BarrierObjective:
    """Mean logistic loss + ``ridge / 2 |c[1:]|²`` − ``mu Σ log(−A c)``, with gradient and Hessian."""

    def __init__(self, X: np.ndarray, y: np.ndarray, A: np.ndarray, ridge: float) -> None:
        self.X, self.y, self.A = X, y, A
        self.reg = np.full(X.shape[1], ridge)
        self.reg[0] = 0.0

    def value(self, c: np.ndarray, mu: float) -> float:
        """The objective; ``inf`` outside the strict feasible set."""
        s = -(self.A @ c)
        if np.any(s <= 0):
            return math.inf
        z = self.X @ c
        loss = np.mean(np.logaddexp(0.0, z) - self.y * z) + 0.5 * c @ (self.reg * c)
        return float(loss - mu * np.sum(np.log(s)))

    def derivatives(self, c: np.ndarray, mu: float) -> tuple[np.ndarray, np.ndarray]:
        """Gradient (K,) and Hessian (K, K) at a strictly feasible ``c``."""
        p = sigmoid(self.X @ c)
        n = len(self.y)
        inv_s = 1.0 / -(self.A @ c)
        g = self.X.T @ (p - self.y) / n + self.reg * c + mu * self.A.T @ inv_s
        H = (self.X * (p * (1 - p))[:, None]).T @ self.X / n + np.diag(self.reg)
        H += mu * (self.A * inv_s[:, None] ** 2).T @ self.A
        return g, H


def _newton(obj: _BarrierObjective, c: np.ndarray, mu: float, max_steps: int = 50) -> np.ndarray:
    """Damped Newton minimisation of the barrier objective at a fixed ``mu``, staying strictly feasible."""
    f = obj.value(c, mu)
    for _ in range(max_steps):
        g, H = obj.derivatives(c, mu)
        d = -np.linalg.solve(H + 1e-12 * np.eye(len(c)), g)
        decrement = -(g @ d)
        if decrement < 1e-14:
            break
        step = 1.0
        while step > 1e-12:
            f_new = obj.value(c + step * d, mu)
            if f_new <= f - 0.25 * step * decrement:
                break
            step *= 0.5
        else:
            break
        c, f = c + step * d, f_new
    return c


def fit_logistic(X: np.ndarray, y: np.ndarray, A: np.ndarray, start: np.ndarray, ridge: float = 1e-6,
                 gap: float = 1e-9) -> np.ndarray:
    """Logistic regression under linear constraints ``A @ c <= 0`` (log-barrier interior-point method).

    Args:
        X: (N, K) features; column 0 is the intercept (ones).
        y: (N,) labels in {0, 1}.
        A: (M, K) constraint rows.
        start: (K,) strictly feasible start (``A @ start < 0``).
        ridge: L2 penalty on every coefficient but the intercept (keeps separable data finite).
        gap: stop once the barrier's bound on the suboptimality, ``M mu``, is below this.

    Returns:
        (K,) coefficients, strictly feasible.
    """
    A = np.asarray(A, dtype=np.float64).reshape(-1, X.shape[1])
    if np.any(A @ start >= 0):
        raise ValueError("the start of fit_logistic must satisfy A @ start < 0 strictly")
    obj = _BarrierObjective(np.asarray(X, np.float64), np.asarray(y, np.float64), A, ridge)
    c, mu = np.asarray(start, dtype=np.float64).copy(), 0.1 / max(len(A), 1)
    while True:
        c = _newton(obj, c, mu)
        if len(A) * mu < gap:
            return c
        mu *= 0.1


def fit_working_region(translation_m: np.ndarray, rotation_rad: np.ndarray, good: np.ndarray,
                       exponents: tuple[tuple[int, int], ...] = DEFAULT_EXPONENTS, max_translation_m: float = 1.0,
                       max_rotation_rad: float = 1.0, ridge: float = 1e-6) -> np.ndarray:
    """Coefficients of ``P(good | t, r)``, non-increasing in ``t`` and ``|r|`` over the sampled domain.

    Args:
        translation_m: (N,) translation between the two scans of each pair, m.
        rotation_rad: (N,) rotation between them, rad (sign ignored).
        good: (N,) whether the pair's alignment error was below the thresholds.
        exponents: K monomials ``t^i |r|^j``; they must include ``(0, 0)`` first, then ``(1, 0)`` and ``(0, 1)``.
        max_translation_m: the samples' translation range, m: monotone on ``[0, max_translation_m]``...
        max_rotation_rad: ... x ``[0, max_rotation_rad]`` (checked on a :data:`MONOTONE_GRID` grid).
        ridge: L2 penalty on the non-intercept coefficients.

    Returns:
        (K,) coefficients.
    """
    exponents = tuple((int(i), int(j)) for i, j in exponents)
    if exponents[0] != (0, 0) or (1, 0) not in exponents or (0, 1) not in exponents:
        raise ValueError("exponents must start with the intercept (0, 0) and include t (1, 0) and r (0, 1)")
    good = np.asarray(good, dtype=np.float64)
    start = np.zeros(len(exponents))  # strictly decreasing: -t - r
    start[[exponents.index((1, 0)), exponents.index((0, 1))]] = -1.0
    mean = float(np.clip(good.mean(), 1e-3, 1 - 1e-3))
    start[0] = math.log(mean / (1 - mean)) + 1.0
    A = monotone_constraints(exponents, max_translation_m, max_rotation_rad)
    return fit_logistic(monomials(translation_m, rotation_rad, exponents), good, A, start, ridge)


# ----------------------------------------------------------------------------------------------------------------
# Policy


def available_presets() -> list[str]:
    """Names of the 2D lidar presets with a shipped model, sorted."""
    return sorted(p.stem for p in MODEL_DIR.glob("*.json"))


@dataclass(frozen=True)
class LearnedKeyscanPolicy:
    """Keyscan criterion from a learned working region (§3.G.7); a :class:`simnav.odometry.srf.KeyscanPolicy`.

    Attributes:
        exponents: K monomials ``t^i |r|^j`` of the logistic model.
        coefficients: (K,) their coefficients.
        p_ratio: the working region is ``P(good | t, r) >= p_ratio * P(good | 0, 0)``.
        margin: safety margin: the motion is scaled by ``1 + margin`` before it is tested (the next scan lies
            one more increment away from the keyscan).
        max_translation_m: translation beyond which there were no samples; farther counts as outside, m.
        max_rotation_rad: rotation beyond which there were no samples; larger counts as outside, rad.
        name: the scanner preset (or file) the model was fitted for.
    """

    exponents: tuple[tuple[int, int], ...]
    coefficients: tuple[float, ...]
    p_ratio: float = 0.9
    margin: float = 0.1
    max_translation_m: float = 1.0
    max_rotation_rad: float = 1.0
    name: str = ""
    _level: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if len(self.exponents) != len(self.coefficients) or not self.exponents:
            raise ConfigError(f"keyscan model '{self.name}': {len(self.exponents)} exponents but "
                              f"{len(self.coefficients)} coefficients")
        if any(i < 0 or j < 0 for i, j in self.exponents):
            raise ConfigError(f"keyscan model '{self.name}': exponents must be >= 0, got {self.exponents}")
        if not 0 < self.p_ratio <= 1:
            raise ConfigError(f"keyscan model '{self.name}': p_ratio must be in (0, 1], got {self.p_ratio}")
        if not self.margin >= 0:
            raise ConfigError(f"keyscan model '{self.name}': margin must be >= 0, got {self.margin}")
        if not (self.max_translation_m > 0 and self.max_rotation_rad > 0):
            raise ConfigError(f"keyscan model '{self.name}': max_translation_m and max_rotation_rad must be > 0")
        object.__setattr__(self, "_level", self.p_ratio * self.probability_good(0.0, 0.0))

    # -- loading ------------------------------------------------------------------------------------------

    @classmethod
    def from_preset(cls, name: str, **overrides) -> LearnedKeyscanPolicy:
        """The shipped model of a 2D lidar preset (e.g. ``"hokuyo_utm30lx"``).

        Args:
            name: preset name; see :func:`available_presets`.
            **overrides: field values replacing the file's (``p_ratio``, ``margin``, ...).

        Raises:
            UnknownNameError: no model for ``name`` (the message lists the available ones).
            ConfigError: the file is malformed.
        """
        path = MODEL_DIR / f"{name}.json"
        if not path.is_file():
            names = ", ".join(available_presets()) or f"(none in {MODEL_DIR})"
            raise UnknownNameError(f"no keyscan model for lidar preset '{name}'; available: {names}")
        return cls.from_file(path, **overrides)

    @classmethod
    def from_file(cls, path: str | Path, **overrides) -> LearnedKeyscanPolicy:
        """A model from a JSON file written by ``scripts/fit_keyscan_models.py``.

        Raises:
            ConfigError: the file is missing, not JSON or lacks a field (the message names the file).
        """
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise ConfigError(f"keyscan model file '{path}': cannot read it as JSON ({err})") from None
        try:
            policy = cls.from_dict(data, name=path.stem)
        except ConfigError as err:
            raise ConfigError(f"keyscan model file '{path}': {err}") from None
        try:
            return replace(policy, **overrides)
        except TypeError as err:
            raise ConfigError(f"keyscan model '{policy.name}': bad override ({err})") from None

    @classmethod
    def from_dict(cls, data: dict, name: str = "") -> LearnedKeyscanPolicy:
        """A model from the parsed JSON (see :meth:`to_dict` for the fields)."""
        try:
            if data.get("format") != FORMAT:
                raise ConfigError(f"'format' must be '{FORMAT}', got {data.get('format')!r}")
            model, domain = data["model"], data["domain"]
            exponents = tuple((int(i), int(j)) for i, j in model["exponents"])
            coefficients = tuple(float(c) for c in model["coefficients"])
            if not all(math.isfinite(c) for c in coefficients):
                raise ConfigError("'model.coefficients' must be finite numbers")
            return cls(exponents, coefficients, p_ratio=float(data["p_ratio"]),
                       margin=float(data.get("margin", 0.1)),
                       max_translation_m=float(domain["max_translation_m"]),
                       max_rotation_rad=float(domain["max_rotation_rad"]),
                       name=str(data.get("preset", name)))
        except ConfigError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise ConfigError(f"missing or invalid field ({type(err).__name__}: {err})") from None

    def to_dict(self) -> dict:
        """The policy's fields in the JSON layout (the fit script adds its protocol and summary)."""
        return {"format": FORMAT, "preset": self.name, "p_ratio": self.p_ratio, "margin": self.margin,
                "model": {"kind": "logistic", "exponents": [list(e) for e in self.exponents],
                          "coefficients": list(self.coefficients)},
                "domain": {"max_translation_m": self.max_translation_m, "max_rotation_rad": self.max_rotation_rad}}

    # -- evaluation ---------------------------------------------------------------------------------------

    def probabilities(self, translation_m: np.ndarray, rotation_rad: np.ndarray) -> np.ndarray:
        """``P(good | t, r)`` for (N,) translations (m) and rotations (rad, sign ignored); returns (N,)."""
        X = monomials(translation_m, rotation_rad, self.exponents)
        return sigmoid(X @ np.asarray(self.coefficients))

    def probability_good(self, translation_m: float, rotation_rad: float) -> float:
        """Probability that aligning two scans ``translation_m`` (m) and ``rotation_rad`` (rad) apart gives
        errors below the fit's thresholds (10 mm and 0.1 deg in the shipped models)."""
        t, r = abs(float(translation_m)), abs(float(rotation_rad))
        z = sum(c * t**i * r**j for (i, j), c in zip(self.exponents, self.coefficients))
        return 1.0 / (1.0 + math.exp(-z)) if z >= 0 else math.exp(z) / (1.0 + math.exp(z))

    @property
    def level(self) -> float:
        """``P(good)`` on the boundary of the working region: ``p_ratio * P(good | 0, 0)``."""
        return self._level

    def inside(self, translation_m: float, rotation_rad: float) -> bool:
        """Whether a motion lies in the working region (no margin)."""
        t, r = abs(translation_m), abs(rotation_rad)
        if not (math.isfinite(t) and math.isfinite(r)) or t > self.max_translation_m or r > self.max_rotation_rad:
            return False
        return self.probability_good(t, r) >= self.level

    def needs_new_keyscan(self, translation_m: float, rotation_rad: float) -> bool:
        """True when the motion from the keyscan, enlarged by the margin, leaves the working region.

        Args:
            translation_m: distance from the keyscan pose, m.
            rotation_rad: heading change from the keyscan pose, rad (signed).
        """
        scale = 1.0 + self.margin
        return not self.inside(scale * translation_m, scale * rotation_rad)

    def max_translation(self, rotation_rad: float = 0.0) -> float:
        """Largest translation in the working region at a given rotation (no margin), m; 0 if none."""
        return self._extent(lambda s: (s, rotation_rad), self.max_translation_m)

    def max_rotation(self, translation_m: float = 0.0) -> float:
        """Largest rotation in the working region at a given translation (no margin), rad; 0 if none."""
        return self._extent(lambda s: (translation_m, s), self.max_rotation_rad)

    def _extent(self, point: Callable[[float], tuple[float, float]], limit: float, tolerance: float = 1e-6) -> float:
        """Bisection for the boundary along ``point(s)``, ``s`` in ``[0, limit]`` (P is monotone in ``s``)."""
        if not self.inside(*point(0.0)):
            return 0.0
        if self.inside(*point(limit)):
            return limit
        lo, hi = 0.0, limit
        while hi - lo > tolerance:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.inside(*point(mid)) else (lo, mid)
        return lo


# ----------------------------------------------------------------------------------------------------------------
# Overlap


def keyscan_overlap(key_ranges_m: np.ndarray, key_geom: LevelGeometry, T_new_key: np.ndarray,
                    new_ranges_m: np.ndarray, new_geom: LevelGeometry, tolerance_m: float, bin_beams: int) -> float:
    """Share of the new scan's view that the keyscan observed too.

    Every valid keyscan point is moved into the new scanner frame and compared with the new beam nearest its
    direction: it is a correspondence when the two ranges differ by less than ``tolerance_m``. The new scan's
    beams are grouped into bins of ``bin_beams`` consecutive beams (so that a surface seen closer than from the
    keyscan, whose keyscan points then spread over more beams, still counts as observed); the overlap is the
    share of bins with a valid new beam that hold a correspondence. Only real keyscan points count: the keyscan
    rendered by :func:`simnav.odometry.rangeflow.warp_scan` bridges depth discontinuities with its segments and
    so fills the directions the keyscan never saw (e.g. what lies beyond a doorway) with surfaces.

    Args:
        key_ranges_m: (n_k,) keyscan ranges, 0 = invalid.
        key_geom: their beam geometry (keyscan scanner frame).
        T_new_key: (3, 3) pose of the keyscan scanner frame in the new scanner frame.
        new_ranges_m: (n,) new ranges, 0 = invalid.
        new_geom: their beam geometry (new scanner frame).
        tolerance_m: largest range difference of a correspondence, m.
        bin_beams: beams per bin (>= 1).

    Returns:
        The overlap in [0, 1]; 0 when the new scan has no valid beam.
    """
    # 1. Keyscan points in the new scanner frame, and the new beam nearest each.
    valid = key_ranges_m > 0
    r = key_ranges_m[valid]
    x, y = r * key_geom.cos[valid], r * key_geom.sin[valid]
    xn = T_new_key[0, 0] * x + T_new_key[0, 1] * y + T_new_key[0, 2]
    yn = T_new_key[1, 0] * x + T_new_key[1, 1] * y + T_new_key[1, 2]
    u = grid_index(np.arctan2(yn, xn), new_geom)
    seen = np.isfinite(u)
    beam = np.rint(u[seen]).astype(np.int64) % new_geom.n
    # 2. Correspondences: the new beam is valid and its range agrees.
    r_new = new_ranges_m[beam]
    match = (r_new > 0) & (np.abs(np.hypot(xn[seen], yn[seen]) - r_new) < tolerance_m)
    # 3. Share of the bins with a valid new beam that hold a correspondence.
    bins = (new_geom.n + bin_beams - 1) // bin_beams
    observed = np.zeros(bins, dtype=bool)
    observed[np.flatnonzero(new_ranges_m > 0) // bin_beams] = True
    matched = np.zeros(bins, dtype=bool)
    matched[beam[match] // bin_beams] = True
    total = np.count_nonzero(observed)
    return float(np.count_nonzero(matched) / total) if total else 0.0
