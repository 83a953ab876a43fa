"""The result every estimator returns: :class:`Calibration`.

Estimates and covariance are held in SI units (m, fraction, rad, s) and
converted to the contract's units (m, fraction, mrad, s) on output.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.bias import CONTRACT_KEYS, NAME_FROM_KEY, PARAMETER_NAMES, RadarBias


@dataclass
class Observability:
    """Observability figures of a linear(ised) estimation problem.

    Attributes
    ----------
    degree : float
        Observability degree ``Deg = lambda_min / lambda_max`` of the
        information matrix (paper 001 eq. 11), computed after Jacobi scaling
        (``D^-1/2 A D^-1/2`` with ``D = diag(A)``) so that it does not depend on
        the parameters' units.
    rank : int
        Numerical rank of the information matrix.
    n_parameters : int
        Number of estimated parameters.
    eigenvalues : ndarray
        Eigenvalues of the scaled information matrix, ascending.
    weakest_direction : ndarray
        Unit eigenvector of the smallest eigenvalue (scaled parameters).
    """

    degree: float
    rank: int
    n_parameters: int
    eigenvalues: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    weakest_direction: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def to_dict(self) -> dict[str, Any]:
        """Contract form: degree, rank, n_parameters (plus the eigenvalues)."""
        return {
            "degree": float(self.degree),
            "rank": int(self.rank),
            "n_parameters": int(self.n_parameters),
            "eigenvalues": [float(v) for v in self.eigenvalues],
        }


@dataclass
class ResidualStats:
    """Residuals of one radar's plots against the reference, before and after correction.

    Each entry of ``before`` / ``after`` maps a measurement name
    (``range_m``, ``azimuth_mrad``, ``elevation_mrad``) to
    ``{"mean": ..., "mean_abs": ..., "rms": ...}`` in that unit.
    """

    n: int
    before: dict[str, dict[str, float]]
    after: dict[str, dict[str, float]]
    chi2_per_dof: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain-dict form for JSON."""
        return {
            "n": self.n,
            "before": self.before,
            "after": self.after,
            "chi2_per_dof": self.chi2_per_dof,
        }


@dataclass
class Calibration:
    """Estimated biases of a radar network with their joint covariance.

    Attributes
    ----------
    method : str
        Estimator name (``ls``, ``fl``, ``fl-ls``, ``wls``, ...).
    radar_ids : list of str
        Radars covered by the result.
    is_3d : dict
        Whether each radar measures elevation.
    labels : list of (radar_id, parameter name)
        Estimated parameters, in the order of ``estimate`` and ``covariance``.
    estimate : ndarray
        Estimates in SI units.
    covariance : ndarray
        Joint covariance in SI units.
    n_plots : dict
        Plots of each radar used by the estimator.
    observability : Observability
    residuals : dict
        :class:`ResidualStats` per radar, where a reference was available.
    warnings : list of str
        Plain-language warnings (weak observability, ...).
    info : dict
        Estimator-specific details (rank, singular values, iterations, ...).
    """

    method: str
    radar_ids: list[str]
    is_3d: dict[str, bool]
    labels: list[tuple[str, str]]
    estimate: NDArray[np.float64]
    covariance: NDArray[np.float64]
    n_plots: dict[str, int]
    observability: Observability
    residuals: dict[str, ResidualStats] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)

    # ----------------------------------------------------------------- queries
    def _position(self, radar_id: str, name: str) -> int | None:
        try:
            return self.labels.index((radar_id, name))
        except ValueError:
            return None

    def _check_radar(self, radar_id: str) -> None:
        if radar_id not in self.radar_ids:
            raise KeyError(f"unknown radar '{radar_id}'; known: {', '.join(self.radar_ids)}")

    def bias(self, radar_id: str) -> RadarBias:
        """The estimated biases of one radar (zero where not estimated), SI units."""
        self._check_radar(radar_id)
        values = {name: 0.0 for name in (*PARAMETER_NAMES, "time_offset")}
        for i, (rid, name) in enumerate(self.labels):
            if rid == radar_id:
                values[name] = float(self.estimate[i])
        return RadarBias(
            values["range_offset"], values["range_gain"], values["azimuth_bias"],
            values["elevation_bias"], values["time_offset"],
        )

    def value(self, radar_id: str, key: str) -> float | None:
        """Estimate in contract units for a contract key; ``None`` if not estimated."""
        self._check_radar(radar_id)
        name = NAME_FROM_KEY[key]
        i = self._position(radar_id, name)
        return None if i is None else float(self.estimate[i] * CONTRACT_KEYS[name][1])

    def sigma(self, radar_id: str, key: str) -> float | None:
        """1-sigma in contract units for a contract key; ``None`` if not estimated."""
        self._check_radar(radar_id)
        name = NAME_FROM_KEY[key]
        i = self._position(radar_id, name)
        if i is None:
            return None
        return float(np.sqrt(max(self.covariance[i, i], 0.0)) * CONTRACT_KEYS[name][1])

    def contract_labels(self) -> list[str]:
        """Labels ``RADAR.key`` in contract units, e.g. ``LAEG.azimuth_bias_mrad``."""
        return [f"{rid}.{CONTRACT_KEYS[name][0]}" for rid, name in self.labels]

    def contract_covariance(self) -> NDArray[np.float64]:
        """Joint covariance in the contract units of :meth:`contract_labels`."""
        scale = np.array([CONTRACT_KEYS[name][1] for _, name in self.labels])
        return self.covariance * np.outer(scale, scale)

    def covariance_block(self, radar_a: str, radar_b: str | None = None) -> NDArray[np.float64]:
        """Covariance block between two radars' parameters (contract units)."""
        radar_b = radar_a if radar_b is None else radar_b
        self._check_radar(radar_a)
        self._check_radar(radar_b)
        ia = [i for i, (rid, _) in enumerate(self.labels) if rid == radar_a]
        ib = [i for i, (rid, _) in enumerate(self.labels) if rid == radar_b]
        return self.contract_covariance()[np.ix_(ia, ib)]

    def correlation(self) -> NDArray[np.float64]:
        """Correlation matrix of the estimated parameters."""
        sd = np.sqrt(np.clip(np.diag(self.covariance), 1e-300, None))
        return self.covariance / np.outer(sd, sd)

    # --------------------------------------------------------------- export
    def to_dict(self) -> dict[str, Any]:
        """The result JSON of the contract (plus optional extra keys)."""
        radars: dict[str, Any] = {}
        for rid in self.radar_ids:
            entry: dict[str, Any] = {}
            sigma: dict[str, float] = {}
            for name in PARAMETER_NAMES:
                key = CONTRACT_KEYS[name][0]
                entry[key] = self.value(rid, key)
                s = self.sigma(rid, key)
                if s is not None:
                    sigma[key] = s
            if self._position(rid, "time_offset") is not None:
                entry["time_offset_s"] = self.value(rid, "time_offset_s")
                sigma["time_offset_s"] = self.sigma(rid, "time_offset_s")
            entry["sigma"] = sigma
            entry["n_plots"] = int(self.n_plots.get(rid, 0))
            if rid in self.residuals:
                entry["residuals"] = self.residuals[rid].to_dict()
            radars[rid] = entry
        return _jsonable({
            "method": self.method,
            "radars": radars,
            "covariance": {
                "labels": self.contract_labels(),
                "matrix": self.contract_covariance().tolist(),
            },
            "observability": self.observability.to_dict(),
            "warnings": list(self.warnings),
            "info": self.info,
        })

    def to_json(self) -> str:
        """The result JSON as text."""
        return json.dumps(self.to_dict(), indent=2, allow_nan=False, default=_jsonable)

    def write_json(self, path: str | Path) -> None:
        """Write the result JSON atomically (temporary file, then rename)."""
        from graphcal.dataset import atomic_write_text

        atomic_write_text(Path(path), self.to_json() + "\n")


def _jsonable(value: Any) -> Any:
    """Convert numpy values (and NaN) to JSON-safe Python values."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        v = float(value)
        return v if np.isfinite(v) else None
    return value


def load_result(path: str | Path) -> dict[str, Any]:
    """Read a result JSON (e.g. ``truth.json`` or ``calibrate --out``) as a dict."""
    with open(path, encoding="utf-8") as handle:
        return json.load(handle)
