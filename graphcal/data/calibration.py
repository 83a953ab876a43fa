"""The result every estimator returns: :class:`Calibration`.

Estimates and covariance are held in SI units (m, fraction, rad, s) and
converted to the contract's units (m, fraction, mrad, s) on output.

The rule: the arrays ``estimate`` and ``covariance`` are SI, like everything
inside graphcal; the methods that take a radar or a contract key answer in
contract units.  Queries in contract units::

    cal.value("LAEG", "azimuth_bias_mrad")
    cal.sigma("LAEG", "azimuth_bias_mrad")
    cal.marginal("LAEG")              # LAEG's covariance block
    cal.marginal("LAEG", "DOLE")      # cross block between LAEG's and DOLE's parameters
    cal.correlation("LAEG", "DOLE")   # unit-free

The joint matrix, with its units in the name::

    cal.covariance_contract           # contract units (m, fraction, mrad, s), the JSON's
    cal.covariance_si                 # SI units (m, fraction, rad, s)

``cal.covariance`` is the SI matrix (``cal.covariance[i, j]`` in rad^2 for two
azimuth terms).  Calling it, ``cal.covariance("LAEG")``, still gives the
contract-unit block of :meth:`Calibration.marginal` but is deprecated (a
``DeprecationWarning``): one name should not answer in two units.  :meth:`Calibration.from_dict` and
:meth:`Calibration.read_json` rebuild a result from its contract JSON so that
the same queries work on a file.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from graphcal.core.errors import ResultError
from graphcal.data.bias import (
    CONTRACT_KEYS,
    ECCENTRICITY_NAMES,
    NAME_FROM_KEY,
    PARAMETER_NAMES,
    RadarBias,
    contract_unit,
)
from graphcal.data.height import HeightModelEstimate


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


class JointCovariance(np.ndarray):
    """The joint covariance of a :class:`Calibration`: an SI array that can be called.

    As an array it is exactly what ``Calibration.covariance`` always was, the
    joint covariance in SI units (m, fraction, rad, s) in the order of
    ``Calibration.labels``: index it, slice it, hand it to numpy.  Calling it
    returns a marginal block in contract units (m, fraction, mrad, s), the same
    as :meth:`Calibration.marginal`::

        cal.covariance[i, j]              # SI element, as before
        cal.covariance("LAEG")            # LAEG's block, contract units
        cal.covariance("LAEG", "DOLE")    # cross block LAEG x DOLE

    ``Calibration.covariance`` hands out a fresh view of the calibration's
    matrix on each access (writes go through to it).  Everything derived from
    it (slices, arithmetic, numpy functions) is a plain ``ndarray``; only the
    attribute itself knows its labels and is callable.
    """

    _owner: Calibration | None

    def __new__(cls, data: ArrayLike, owner: Calibration | None = None) -> JointCovariance:
        obj = np.asarray(data, dtype=float).view(cls)
        obj._owner = owner
        return obj

    def __array_finalize__(self, obj: object) -> None:
        # Views made by ndarray methods (.T, .copy(), ...) lose the labels.
        self._owner = None

    def __call__(self, radar_a: str, radar_b: str | None = None) -> NDArray[np.float64]:
        """Covariance block of ``radar_a`` (with ``radar_b``) in contract units.

        Parameters
        ----------
        radar_a : str
            Radar of the rows.
        radar_b : str, optional
            Radar of the columns; default ``radar_a`` (its marginal covariance).

        Returns
        -------
        ndarray
            Shape ``(n_a, n_b)``: rows and columns in the order of each radar's
            estimated parameters (:meth:`Calibration.marginal_labels`), units
            the products of the contract units (m, fraction, mrad, s).
        """
        import warnings

        warnings.warn(
            "cal.covariance(radar) gives contract units (mrad) while cal.covariance[i, j] is "
            "SI (rad): use cal.marginal(radar) for contract-unit blocks, cal.covariance_si "
            "or cal.covariance_contract for the whole matrix",
            DeprecationWarning, stacklevel=2)
        owner = self._owner
        if owner is None:
            raise TypeError(
                "only Calibration.covariance itself can be called; this array was derived "
                "from it and has no labels"
            )
        if self.shape != (len(owner.labels), len(owner.labels)):
            raise ValueError(
                f"covariance of shape {self.shape} does not match the calibration's "
                f"{len(owner.labels)} labels (the calibration was changed since)"
            )
        return _contract_block(np.asarray(self), owner, radar_a, radar_b)

    def __getitem__(self, index: Any) -> Any:
        item = super().__getitem__(index)
        return item.view(np.ndarray) if isinstance(item, np.ndarray) else item

    def __array_ufunc__(
        self, ufunc: np.ufunc, method: str, *inputs: Any, out: Any = None, **kwargs: Any
    ) -> Any:
        inputs = tuple(_plain(x) for x in inputs)
        if out is not None:
            kwargs["out"] = tuple(_plain(x) for x in out)
        result = getattr(ufunc, method)(*inputs, **kwargs)
        if out is not None:  # in place: hand back the caller's own output arrays
            return out[0] if len(out) == 1 else out
        return result

    def __array_function__(
        self, func: Any, types: Any, args: tuple[Any, ...], kwargs: dict[str, Any]
    ) -> Any:
        return func(*_plain(args), **_plain(kwargs))


def _plain(value: Any) -> Any:
    """``value`` with every :class:`JointCovariance` in it viewed as a plain ndarray."""
    if isinstance(value, JointCovariance):
        return value.view(np.ndarray)
    if isinstance(value, tuple | list):
        return type(value)(_plain(v) for v in value)
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _parameter_name(key: str) -> str:
    """Internal parameter name of a contract key (``azimuth_bias_mrad`` -> ``azimuth_bias``)."""
    try:
        return NAME_FROM_KEY[key]
    except KeyError:
        raise KeyError(
            f"unknown parameter key '{key}'; known: {', '.join(NAME_FROM_KEY)}"
        ) from None


def _contract_scale(labels: list[tuple[str, str]]) -> NDArray[np.float64]:
    """Factor from SI to the contract unit of each label."""
    return np.array([CONTRACT_KEYS[name][1] for _, name in labels], dtype=float)


def _contract_block(
    covariance_si: NDArray[np.float64], cal: Calibration, radar_a: str, radar_b: str | None
) -> NDArray[np.float64]:
    """Block ``radar_a x radar_b`` of an SI covariance over ``cal.labels``, contract units."""
    ia, ib = cal._indices(radar_a), cal._indices(radar_b if radar_b is not None else radar_a)
    scale = _contract_scale(cal.labels)
    return covariance_si[np.ix_(ia, ib)] * np.outer(scale[ia], scale[ib])


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
    covariance : JointCovariance
        Joint covariance in SI units (m, fraction, rad, s), shape ``(len(labels),
        len(labels))``: the constructor takes it in SI.  Reading gives a
        :class:`JointCovariance`, an SI ndarray view (indexing it gives SI
        elements, as always) that can also be called for contract-unit blocks:
        ``cal.covariance("LAEG")``, ``cal.covariance("LAEG", "DOLE")``.  To make the
        units explicit use :attr:`covariance_si` (SI) or :attr:`covariance_contract`
        (contract units, the JSON's), whose names say what they hold.
    n_plots : dict
        Plots of each radar used by the estimator.
    observability : Observability
    residuals : dict
        :class:`ResidualStats` per radar, where a reference was available.
    warnings : list of str
        Plain-language warnings (weak observability, ...).
    info : dict
        Estimator-specific details (rank, singular values, iterations, ...).
    fixed : dict
        ``{(radar_id, parameter name): value SI}``: terms held at a known value,
        not estimated (no sigma); :meth:`bias` and :meth:`value` include them.
    information : ndarray or None
        Fisher information the data alone give on the parameters (SI, ``labels``
        order, priors excluded), when the estimator computes it; the pipeline's
        analyses read it.  Not part of the result JSON.
    bound : dict or None
        The Cramér-Rao bound of the estimator's own model, when it computes one:
        ``{"covariance": (p, p) over labels (SI, priors included), "atmosphere_sigma":
        {key: sigma} or None, "model": description}``.  Not part of the result JSON
        (its sigmas are, as ``info["crlb_sigma"]``).
    atmosphere : HeightModelEstimate or None
        The height model of pressure altitudes (contract v2), when the dataset's
        plots carry pressure altitudes and the estimator models them: the result
        JSON's ``atmosphere`` block.  It is not in ``labels``: ``covariance``
        stays over the radar terms, and the block carries the pair's own
        covariance and its cross-covariance with them.
    """

    method: str
    radar_ids: list[str]
    is_3d: dict[str, bool]
    labels: list[tuple[str, str]]
    estimate: NDArray[np.float64]
    covariance: NDArray[np.float64]  # a property over ``_covariance``, defined below the class
    n_plots: dict[str, int]
    observability: Observability
    residuals: dict[str, ResidualStats] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    fixed: dict[tuple[str, str], float] = field(default_factory=dict)
    information: NDArray[np.float64] | None = field(default=None, repr=False, compare=False)
    bound: dict[str, Any] | None = field(default=None, repr=False, compare=False)
    atmosphere: HeightModelEstimate | None = None
    series: dict[str, Any] | None = field(default=None, repr=False)
    events: list[dict[str, Any]] | None = None

    # ----------------------------------------------------------------- display
    #: Radars :meth:`__repr__` lists before summarising the rest.
    REPR_RADARS = 12

    def __repr__(self) -> str:
        """A short summary: the method and counts, then one line per radar (value ± sigma).

        At most :attr:`REPR_RADARS` radars are listed; the rest are counted.
        """
        n = len(self.radar_ids)
        head = (f"Calibration(method={self.method!r}, {n} radar{'s' if n != 1 else ''}, "
                f"{len(self.labels)} estimated parameters, {len(self.warnings)} warnings"
                + (", with series" if self.series is not None else "") + ")")
        lines = [head]
        frame = self.to_frame()
        for rid in self.radar_ids[: self.REPR_RADARS]:
            rows = frame[frame["radar"] == rid]
            terms = [f"{row.parameter} {_short(row.value)}"
                     + (" (fixed)" if row.fixed else f" ± {_short(row.sigma, 2)}")
                     for row in rows.itertuples(index=False)]
            lines.append(f"  {rid}: " + (", ".join(terms) if terms else "no terms"))
        if len(self.radar_ids) > self.REPR_RADARS:
            lines.append(f"  ... and {len(self.radar_ids) - self.REPR_RADARS} more radars")
        return "\n".join(lines)

    def to_frame(self) -> Any:
        """The estimates as a table: one row per radar and bias term, contract units.

        Returns
        -------
        pandas.DataFrame
            Columns ``radar``, ``parameter`` (contract key, e.g.
            ``azimuth_bias_mrad``), ``value``, ``sigma`` (1-sigma, NaN for a fixed
            term), ``unit`` (``m``, ``fraction``, ``mrad``, ``s``) and ``fixed``
            (held at a known value, not estimated).  Radars in :attr:`radar_ids`
            order, terms in contract order; the terms a radar has neither
            estimated nor fixed are left out.
        """
        import pandas as pd

        rows = []
        for rid in self.radar_ids:
            for name, (key, _) in CONTRACT_KEYS.items():
                estimated = self._position(rid, name) is not None
                if not estimated and (rid, name) not in self.fixed:
                    continue
                sigma = self.sigma(rid, key) if estimated else None
                rows.append({"radar": rid, "parameter": key, "value": self.value(rid, key),
                             "sigma": np.nan if sigma is None else sigma,
                             "unit": contract_unit(key), "fixed": not estimated})
        columns = ["radar", "parameter", "value", "sigma", "unit", "fixed"]
        return pd.DataFrame(rows, columns=columns).astype({"value": float, "sigma": float,
                                                           "fixed": bool})

    # ----------------------------------------------------------------- queries
    def _position(self, radar_id: str, name: str) -> int | None:
        try:
            return self.labels.index((radar_id, name))
        except ValueError:
            return None

    def _check_radar(self, radar_id: str) -> None:
        if radar_id not in self.radar_ids:
            raise KeyError(f"unknown radar '{radar_id}'; known: {', '.join(self.radar_ids)}")

    def _indices(self, radar_id: str) -> list[int]:
        """Positions of one radar's parameters in ``labels``."""
        self._check_radar(radar_id)
        return [i for i, (rid, _) in enumerate(self.labels) if rid == radar_id]

    def bias(self, radar_id: str) -> RadarBias:
        """The estimated biases of one radar (zero where not estimated), SI units."""
        self._check_radar(radar_id)
        values = {name: 0.0 for name in (*PARAMETER_NAMES, "time_offset", *ECCENTRICITY_NAMES)}
        for (rid, name), value in self.fixed.items():
            if rid == radar_id:
                values[name] = float(value)
        for i, (rid, name) in enumerate(self.labels):
            if rid == radar_id:
                values[name] = float(self.estimate[i])
        return RadarBias(
            values["range_offset"], values["range_gain"], values["azimuth_bias"],
            values["elevation_bias"], values["time_offset"],
            azimuth_sin_rad=values["azimuth_sin"], azimuth_cos_rad=values["azimuth_cos"],
        )

    def value(self, radar_id: str, key: str) -> float | None:
        """Estimate (or fixed value) in contract units for a contract key; ``None`` if neither.

        Parameters
        ----------
        radar_id : str
            Radar id.
        key : str
            Contract key: ``range_offset_m`` [m], ``range_gain`` [fraction],
            ``azimuth_bias_mrad`` [mrad], ``elevation_bias_mrad`` [mrad] or
            ``time_offset_s`` [s].
        """
        self._check_radar(radar_id)
        name = _parameter_name(key)
        i = self._position(radar_id, name)
        if i is None:
            fixed = self.fixed.get((radar_id, name))
            return None if fixed is None else float(fixed * CONTRACT_KEYS[name][1])
        return float(self.estimate[i] * CONTRACT_KEYS[name][1])

    def sigma(self, radar_id: str, key: str) -> float | None:
        """1-sigma in contract units for a contract key; ``None`` if not estimated.

        Parameters
        ----------
        radar_id : str
            Radar id.
        key : str
            Contract key, as for :meth:`value` (``time_offset_s`` included).

        Returns
        -------
        float or None
            Square root of the marginal variance, in the key's unit (m,
            fraction, mrad, s); ``inf`` or NaN for an undetermined parameter.
        """
        self._check_radar(radar_id)
        name = _parameter_name(key)
        i = self._position(radar_id, name)
        if i is None:
            return None
        return float(np.sqrt(max(self._covariance[i, i], 0.0)) * CONTRACT_KEYS[name][1])

    def contract_labels(self) -> list[str]:
        """Labels ``RADAR.key`` in contract units, e.g. ``LAEG.azimuth_bias_mrad``."""
        return [f"{rid}.{CONTRACT_KEYS[name][0]}" for rid, name in self.labels]

    def contract_covariance(self) -> NDArray[np.float64]:
        """Joint covariance in the contract units of :meth:`contract_labels`."""
        scale = _contract_scale(self.labels)
        return self._covariance * np.outer(scale, scale)

    @property
    def covariance_contract(self) -> NDArray[np.float64]:
        """Joint covariance in contract units (m, fraction, mrad, s), ``labels`` order.

        The units of :meth:`sigma`, :meth:`marginal`, ``covariance(radar)`` and the
        result JSON's ``covariance.matrix``: ``sqrt(covariance_contract[i, i])`` is
        the sigma of ``contract_labels()[i]``.  A fresh array (writes do not go back).
        """
        return self.contract_covariance()

    @property
    def covariance_si(self) -> NDArray[np.float64]:
        """Joint covariance in SI units (m, fraction, rad, s), ``labels`` order.

        What the estimators compute and ``cal.covariance[i, j]`` indexes; a plain
        ndarray view of the calibration's matrix.  Assign through ``covariance``.
        """
        return self._covariance.view(np.ndarray)

    def marginal_labels(self, radar_id: str) -> list[str]:
        """Contract keys of one radar's estimated parameters, in covariance order.

        These label the rows (and columns) of :meth:`marginal`, e.g.
        ``["range_offset_m", "range_gain", "azimuth_bias_mrad"]``.
        """
        return [CONTRACT_KEYS[self.labels[i][1]][0] for i in self._indices(radar_id)]

    def marginal(self, radar_a: str, radar_b: str | None = None) -> NDArray[np.float64]:
        """Marginal covariance block of one radar, or cross block of two, contract units.

        Parameters
        ----------
        radar_a : str
            Radar of the rows.
        radar_b : str, optional
            Radar of the columns; default ``radar_a``.

        Returns
        -------
        ndarray
            Shape ``(n_a, n_b)``, rows and columns ordered as
            :meth:`marginal_labels` of each radar; entries in the products of
            the contract units (m, fraction, mrad, s), e.g. m·mrad.
            ``marginal(b, a)`` is ``marginal(a, b).T``.
        """
        return _contract_block(self._covariance, self, radar_a, radar_b)

    def covariance_block(self, radar_a: str, radar_b: str | None = None) -> NDArray[np.float64]:
        """Same as :meth:`marginal` (kept for existing callers)."""
        return self.marginal(radar_a, radar_b)

    def correlation(
        self, radar_a: str | None = None, radar_b: str | None = None
    ) -> NDArray[np.float64]:
        """Correlation coefficients of the estimated parameters (unit-free).

        Parameters
        ----------
        radar_a : str, optional
            Without it: the full matrix over ``labels``.  With it: the rows of
            this radar's parameters only.
        radar_b : str, optional
            Columns of this radar's parameters; default ``radar_a``.

        Returns
        -------
        ndarray
            ``rho_ij = C_ij / sqrt(C_ii C_jj)``; NaN where a variance is
            infinite or undefined.
        """
        cov = self._covariance
        sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
        rho = cov / np.outer(sd, sd)
        if radar_a is None:
            if radar_b is not None:
                raise TypeError("correlation(): give radar_a when radar_b is given")
            return rho
        ia = self._indices(radar_a)
        ib = self._indices(radar_b if radar_b is not None else radar_a)
        return rho[np.ix_(ia, ib)]

    # ----------------------------------------------------------------- import
    @classmethod
    def from_dict(
        cls, data: Mapping[str, Any], *, source: str | Path | None = None
    ) -> Calibration:
        """Rebuild a calibration from its contract result JSON (already parsed).

        Reads ``radars`` (values in contract units, ``n_plots``, ``residuals``),
        ``covariance.labels`` (``RADAR.key``) and ``covariance.matrix`` (in the
        units of the labels), and ``method``, ``observability``, ``warnings``,
        ``info`` and ``atmosphere`` (contract v2) when present.  Values and
        covariance are converted back to SI, so every query (:meth:`value`,
        :meth:`sigma`, :meth:`marginal`, ``covariance(...)``, :meth:`correlation`)
        works as on the estimator's own result, and ``to_dict`` gives the same
        JSON back.  ``null`` values
        (NaN, infinite variance) become NaN.  Without an ``observability``
        entry the degree is NaN and the rank 0 (not recorded).  ``is_3d`` is
        true where an elevation bias is estimated (all the file tells).

        Parameters
        ----------
        data : mapping
            The parsed JSON.
        source : str or Path, optional
            File name used in error messages.

        Raises
        ------
        ResultError
            A missing or malformed field, naming the file and the field.
        """

        def fail(message: str, where: str | None = None) -> ResultError:
            return ResultError(message, path=source, field=where)

        def number(value: Any, where: str) -> float:
            """A JSON number (``null`` -> NaN) or a ResultError naming the field."""
            if value is None:
                return np.nan
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise fail(f"{value!r} is not a number", where)
            if not math.isfinite(value):  # NaN or Infinity: not JSON; the contract has null
                raise fail(f"{value!r} is not a finite number (write null)", where)
            return float(value)

        if not isinstance(data, Mapping):
            raise fail("not a result JSON object")
        radars = data.get("radars")
        if not isinstance(radars, Mapping):
            raise fail("missing or not an object", "radars")
        for rid, entry in radars.items():
            if not isinstance(entry, Mapping):
                raise fail("not an object", f"radars.{rid}")
        cov_entry = data.get("covariance")
        if not isinstance(cov_entry, Mapping):
            raise fail("missing or not an object", "covariance")
        raw_labels = cov_entry.get("labels")
        if not isinstance(raw_labels, list):
            raise fail("missing or not a list", "covariance.labels")
        labels: list[tuple[str, str]] = []
        for text in raw_labels:
            rid, _, key = str(text).rpartition(".")
            if not rid or key not in NAME_FROM_KEY:
                raise fail(f"'{text}' is not RADAR.key with a contract key", "covariance.labels")
            if rid not in radars:
                raise fail(f"'{text}' names a radar missing from 'radars'", "covariance.labels")
            labels.append((rid, NAME_FROM_KEY[key]))
        if len(set(labels)) != len(labels):
            raise fail("duplicate labels", "covariance.labels")
        p = len(labels)
        rows = cov_entry.get("matrix")
        if not isinstance(rows, list) or len(rows) != p or any(
            not isinstance(row, list) or len(row) != p for row in rows
        ):
            raise fail(f"must be a {p} x {p} list of rows (one per label)", "covariance.matrix")
        matrix = np.array(
            [[number(v, "covariance.matrix") for v in row] for row in rows], dtype=float
        ).reshape(p, p)
        problem = covariance_problem(matrix, [str(text) for text in raw_labels])
        if problem is not None:
            raise fail(problem, "covariance.matrix")
        scale = _contract_scale(labels)
        estimate = np.array(
            [
                number(radars[rid].get(CONTRACT_KEYS[name][0]),
                       f"radars.{rid}.{CONTRACT_KEYS[name][0]}")
                for rid, name in labels
            ],
            dtype=float,
        ) / scale
        _check_result_values(radars, labels, matrix, fail)

        radar_ids = [str(rid) for rid in radars]
        residuals: dict[str, ResidualStats] = {}
        n_plots: dict[str, int] = {}
        try:
            for rid in radar_ids:
                where = f"radars.{rid}.n_plots"
                n_plots[rid] = int(radars[rid].get("n_plots") or 0)
                res = radars[rid].get("residuals")
                where = f"radars.{rid}.residuals"
                if isinstance(res, Mapping):
                    residuals[rid] = ResidualStats(
                        int(res.get("n", 0)), dict(res.get("before", {})),
                        dict(res.get("after", {})), res.get("chi2_per_dof"),
                    )
            fixed: dict[tuple[str, str], float] = {}
            for rid in radar_ids:
                where = f"radars.{rid}.fixed"
                for key, value in dict(radars[rid].get("fixed") or {}).items():
                    name = NAME_FROM_KEY[key]
                    fixed[(rid, name)] = float(value) / CONTRACT_KEYS[name][1]
            where = "observability"
            obs = data.get("observability")
            if isinstance(obs, Mapping):
                observability = Observability(
                    number(obs.get("degree"), "observability.degree"),
                    int(obs.get("rank", 0)),
                    int(obs.get("n_parameters", p)),
                    np.asarray(obs.get("eigenvalues", []), dtype=float),
                )
            else:
                observability = Observability(np.nan, 0, p)
            where = "warnings"
            warnings = [str(w) for w in data.get("warnings") or []]
            where = "info"
            info = dict(data.get("info") or {})
            where = "atmosphere"
            atmosphere = None
            if data.get("atmosphere") is not None:
                atmosphere = HeightModelEstimate.from_dict(data["atmosphere"])
            where = "series"
            series = _read_series(data.get("series"))
            where = "events"
            events = None if series is None else [dict(e) for e in data.get("events") or []]
        except (TypeError, ValueError, KeyError) as exc:
            if isinstance(exc, ResultError):
                raise
            raise fail(f"malformed ({exc})", where) from None
        return cls(
            method=str(data.get("method", "")),
            radar_ids=radar_ids,
            is_3d={rid: (rid, "elevation_bias") in labels for rid in radar_ids},
            labels=labels,
            estimate=estimate,
            covariance=matrix / np.outer(scale, scale),
            n_plots=n_plots,
            observability=observability,
            residuals=residuals,
            warnings=warnings,
            info=info,
            fixed=fixed,
            atmosphere=atmosphere,
            series=series,
            events=events,
        )

    @classmethod
    def read_json(cls, path: str | Path) -> Calibration:
        """Read a result JSON file (``calibrate --out``) with :meth:`from_dict`.

        Raises
        ------
        ResultError
            The file is missing or unreadable, not JSON, or not a result with
            a covariance; the message names the file (and the field).
        """
        try:
            text = Path(path).read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ResultError("no such file", path=path) from None
        except OSError as exc:
            raise ResultError(f"cannot read: {exc.strerror or exc}", path=path) from None
        except UnicodeDecodeError:
            raise ResultError("not UTF-8 text", path=path) from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ResultError(
                f"not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})", path=path
            ) from None
        return cls.from_dict(data, source=path)

    # --------------------------------------------------------------- export
    def to_dict(self) -> dict[str, Any]:
        """The result JSON of the contract (plus optional extra keys)."""
        radars: dict[str, Any] = {}
        # Contract v2: the eccentricity keys appear (null where not estimated) once any
        # radar has them; a version-1 result keeps exactly the version-1 keys.
        eccentric = any(name in ECCENTRICITY_NAMES for _, name in self.labels) or any(
            name in ECCENTRICITY_NAMES for _, name in self.fixed)
        for rid in self.radar_ids:
            entry: dict[str, Any] = {}
            sigma: dict[str, float] = {}
            fixed: dict[str, float] = {}
            for name in PARAMETER_NAMES:
                key = CONTRACT_KEYS[name][0]
                i = self._position(rid, name)
                # The contract: null where not estimated; known (fixed) values go to "fixed".
                entry[key] = None if i is None else self.value(rid, key)
                if i is None and (rid, name) in self.fixed:
                    fixed[key] = self.value(rid, key)
                s = self.sigma(rid, key)
                if s is not None:
                    sigma[key] = s
            if self._position(rid, "time_offset") is not None:
                entry["time_offset_s"] = self.value(rid, "time_offset_s")
                sigma["time_offset_s"] = self.sigma(rid, "time_offset_s")
            for name in ECCENTRICITY_NAMES if eccentric else ():
                key = CONTRACT_KEYS[name][0]
                entry[key] = self.value(rid, key)
                if self._position(rid, name) is not None:
                    sigma[key] = self.sigma(rid, key)
            entry["sigma"] = sigma
            if fixed:
                entry["fixed"] = fixed
            entry["n_plots"] = int(self.n_plots.get(rid, 0))
            if rid in self.residuals:
                entry["residuals"] = self.residuals[rid].to_dict()
            radars[rid] = entry
        document: dict[str, Any] = {"method": self.method, "radars": radars}
        if self.atmosphere is not None:  # contract v2; absent from version-1 results
            document["atmosphere"] = self.atmosphere.to_dict()
        if self.series is not None:  # contract v2 --window
            document["series"] = self.series
            document["events"] = list(self.events or [])
        return _jsonable({
            **document,
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
        from graphcal.core.atomic import atomic_write_text

        atomic_write_text(Path(path), self.to_json() + "\n")


def _short(value: float | None, digits: int = 4) -> str:
    """A number in ``digits`` significant digits (``nan`` for a missing one)."""
    if value is None or not np.isfinite(value):
        return "nan" if value is None or np.isnan(value) else str(value)
    return f"{value:.{digits}g}"


#: Largest |range_gain| a result may carry [fraction]: 10 %.  No radar's range scale is
#: that far off; a gain of -1 (ranges in other units, a sign lost) would correct every
#: range to infinity.
MAX_RESULT_RANGE_GAIN = 0.1
#: Largest |value| of the angular biases [mrad]: half a turn in azimuth (and the
#: eccentricity terms), a quarter turn in elevation.
MAX_RESULT_ANGLE_MRAD = {"azimuth_bias_mrad": 1000.0 * math.pi,
                         "azimuth_sin_mrad": 1000.0 * math.pi,
                         "azimuth_cos_mrad": 1000.0 * math.pi,
                         "elevation_bias_mrad": 500.0 * math.pi}
#: Relative tolerance between a result's ``sigma`` entry and the square root of the
#: covariance's diagonal (the JSON holds both; they must tell the same).
SIGMA_TOLERANCE = 1e-3


def bias_value_problem(key: str, value: float) -> str | None:
    """What is wrong with a result's bias value (contract key and units), or ``None``.

    Every value must be finite; ``range_gain`` within :data:`MAX_RESULT_RANGE_GAIN`
    (10 %), the angular biases within :data:`MAX_RESULT_ANGLE_MRAD`.
    """
    if not math.isfinite(value):
        return f"{value!r} is not a finite number"
    if key == "range_gain" and abs(value) > MAX_RESULT_RANGE_GAIN:
        return (f"{value:.6g} is beyond ±{MAX_RESULT_RANGE_GAIN:g} (±{MAX_RESULT_RANGE_GAIN:.0%})"
                ": no radar's range scale is that far off, and correcting with it would "
                "give meaningless ranges (a gain of -1 divides by zero); a result of "
                "another tool or in other units?")
    limit = MAX_RESULT_ANGLE_MRAD.get(key)
    if limit is not None and abs(value) > limit:
        return (f"{value:.6g} mrad is beyond ±{limit:.0f} mrad: an angle in other units "
                "(degrees, microradians)?")
    return None


def sigma_problem(value: Any) -> str | None:
    """What is wrong with a result's ``sigma`` entry, or ``None`` (``null`` passes:
    an undetermined parameter)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{value!r} is not a number"
    if not math.isfinite(value) or value < 0.0:
        return f"{value!r} is not a finite number >= 0 (a 1-sigma)"
    return None


#: Relative tolerances of :func:`covariance_problem`: asymmetry against
#: ``sqrt(C_ii C_jj)``, and the most negative eigenvalue of the correlation matrix.
SYMMETRY_TOLERANCE = 1e-6
PSD_TOLERANCE = 1e-6


def covariance_problem(matrix: NDArray[np.float64], labels: list[str]) -> str | None:
    """What is wrong with a result's covariance matrix, or ``None`` when it is valid.

    A valid covariance has no negative variance, is symmetric and is positive
    semi-definite, within relative tolerances (:data:`SYMMETRY_TOLERANCE` of
    ``sqrt(C_ii C_jj)``; the correlation matrix's smallest eigenvalue not below
    ``-PSD_TOLERANCE``).  NaN entries (``null`` in the JSON: an undetermined
    parameter's infinite variance) are allowed; the checks apply to the parameters
    with a finite variance.

    Parameters
    ----------
    matrix : ndarray, shape (p, p)
        The covariance, any consistent units.
    labels : list of str
        The ``RADAR.key`` label of each row, for the message.
    """
    diagonal = np.diag(matrix)
    for i in np.flatnonzero(diagonal < 0.0):
        return f"negative variance {diagonal[i]:.6g} of {labels[i]}"
    known = np.flatnonzero(np.isfinite(diagonal))
    block = matrix[np.ix_(known, known)]
    both = np.isfinite(block) & np.isfinite(block.T)
    size = np.sqrt(np.outer(diagonal[known], diagonal[known]))
    asym = np.where(both, np.abs(block - block.T) - SYMMETRY_TOLERANCE * size, -np.inf)
    if asym.size and asym.max() > 0.0:
        i, j = np.unravel_index(np.argmax(asym), asym.shape)
        a, b = labels[known[i]], labels[known[j]]
        return (f"not symmetric: {block[i, j]:.6g} for ({a}, {b}) but {block[j, i]:.6g} "
                f"for ({b}, {a})")
    sigma = np.sqrt(diagonal[known])
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.where(both, block, 0.0) / np.outer(sigma, sigma)
    zero = sigma == 0.0
    if np.any(zero):  # a zero variance allows only zero covariances
        off = np.where(both, block, 0.0)[zero]
        if np.any(np.abs(off) > 0.0):
            row = labels[known[np.flatnonzero(zero)[0]]]
            return f"not positive semi-definite: {row} has zero variance but a covariance"
        rho = rho[np.ix_(~zero, ~zero)]
    if rho.size == 0:
        return None
    rho = 0.5 * (rho + rho.T)
    smallest = float(np.linalg.eigvalsh(rho)[0])
    if smallest < -PSD_TOLERANCE:
        off = np.abs(rho - np.diag(np.diag(rho)))
        i, j = np.unravel_index(np.argmax(off), off.shape)
        names = [labels[k] for k in known[~zero]]
        return (f"not positive semi-definite (smallest eigenvalue of the correlation "
                f"matrix {smallest:.3g}; the largest correlation is {rho[i, j]:.3g}, "
                f"between {names[i]} and {names[j]})")
    return None


def _check_result_values(radars: Mapping[str, Any], labels: list[tuple[str, str]],
                         matrix: NDArray[np.float64], fail: Any) -> None:
    """Raise ``fail(message, field)`` for a result whose values cannot be right.

    Every estimated (labelled) value must be a finite number within its limits
    (:func:`bias_value_problem`); a radar's non-null bias keys must be labelled in
    the covariance (or held fixed); each ``sigma`` entry must be ``null`` or a finite
    number >= 0, belong to a labelled parameter and agree with the covariance's
    diagonal (:data:`SIGMA_TOLERANCE`).
    """
    position = {label: i for i, label in enumerate(labels)}
    for rid, entry in radars.items():
        fixed = entry.get("fixed") if isinstance(entry.get("fixed"), Mapping) else {}
        for key, value in entry.items():
            if key not in NAME_FROM_KEY:
                continue
            where = f"radars.{rid}.{key}"
            labelled = (rid, NAME_FROM_KEY[key]) in position
            if value is None:
                if labelled and math.isfinite(matrix[position[(rid, NAME_FROM_KEY[key])],
                                                     position[(rid, NAME_FROM_KEY[key])]]):
                    raise fail("null, but the covariance gives it a finite variance (an "
                               "estimated value needs a number; null is for an undetermined "
                               "one)", where)
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise fail(f"{value!r} is not a number", where)
            problem = bias_value_problem(key, float(value))
            if problem is not None:
                raise fail(problem, where)
            if not labelled and key not in fixed:
                raise fail("has a value but no covariance label (an estimated value needs "
                           "one; a known one goes under 'fixed')", where)
        for key, value in dict(fixed).items():
            if key in NAME_FROM_KEY and value is not None:
                problem = (bias_value_problem(key, float(value))
                           if isinstance(value, int | float) and not isinstance(value, bool)
                           else f"{value!r} is not a number")
                if problem is not None:
                    raise fail(problem, f"radars.{rid}.fixed.{key}")
        sigmas = entry.get("sigma")
        if sigmas is None:
            continue
        if not isinstance(sigmas, Mapping):
            raise fail("not an object", f"radars.{rid}.sigma")
        for key, value in sigmas.items():
            where = f"radars.{rid}.sigma.{key}"
            problem = sigma_problem(value)
            if problem is not None:
                raise fail(problem, where)
            if key not in NAME_FROM_KEY or (rid, NAME_FROM_KEY[key]) not in position:
                raise fail("a sigma for a parameter the covariance does not label", where)
            i = position[(rid, NAME_FROM_KEY[key])]
            variance = float(matrix[i, i])
            if value is not None and math.isfinite(variance):
                expected = math.sqrt(max(variance, 0.0))
                if abs(value - expected) > SIGMA_TOLERANCE * max(expected, abs(value)) + 1e-300:
                    raise fail(f"{value:.6g} disagrees with the covariance's diagonal "
                               f"(sqrt {expected:.6g})", where)


def _read_series(value: Any) -> dict[str, Any] | None:
    """A result's ``series`` block, checked: a window length and, per radar, windows
    with their span and finite values (``KeyError``/``ValueError`` otherwise)."""
    if value is None:
        return None
    window_s = float(value["window_s"])
    if not (np.isfinite(window_s) and window_s > 0):
        raise ValueError(f"window_s must be a positive duration, not {window_s}")
    radars = {}
    for rid, windows in dict(value["radars"]).items():
        entries = []
        for entry in windows:
            entry = dict(entry)
            for key in ("t_start_s", "t_end_s"):
                entry[key] = float(entry[key])
            for key, number in entry.items():
                if isinstance(number, float) and not np.isfinite(number):
                    raise ValueError(f"{rid} window at {entry['t_start_s']} s: {key} is "
                                     "not finite")
            entries.append(entry)
        radars[str(rid)] = entries
    return {**dict(value), "window_s": window_s, "radars": radars}


def _get_covariance(self: Calibration) -> JointCovariance:
    return JointCovariance(self._covariance, owner=self)


def _set_covariance(self: Calibration, value: ArrayLike) -> None:
    self._covariance = np.asarray(value, dtype=float)  # a plain view, never a copy of floats


# Set after @dataclass has collected the fields, so ``covariance`` stays an
# ordinary constructor argument without a default.
Calibration.covariance = property(  # type: ignore[assignment]
    _get_covariance,
    _set_covariance,
    doc="Joint covariance, indexed in SI units (covariance_si), callable for contract-unit "
        "blocks (JointCovariance); covariance_contract is the whole matrix in contract units.",
)


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


def read_height_model(source: Any) -> tuple[float, float] | None:
    """``(height_offset_m, height_scale)`` of a result's ``atmosphere`` block (contract v2).

    ``source``: a result JSON path (a calibration or a simulation's ``truth.json``) or a
    :class:`Calibration`; ``None`` when it has no height model (or is anything else,
    e.g. a mapping of plain biases).
    """
    if isinstance(source, str | Path):
        block = load_result(source).get("atmosphere")
        if not isinstance(block, Mapping):
            return None
        return float(block["height_offset_m"]), float(block["height_scale"])
    if isinstance(source, Calibration) and source.atmosphere is not None:
        return source.atmosphere.height_offset_m, source.atmosphere.height_scale
    return None


def read_biases(path: str | Path) -> dict[str, RadarBias]:
    """Per-radar biases from a result JSON: a calibration or a simulation's ``truth.json``.

    :meth:`graphcal.data.calibration.Calibration.read_json` needs a ``covariance``
    entry, which ``truth.json`` does not have; this reads only the values
    (``radars.RADAR.<contract key>`` and ``radars.RADAR.fixed``), in contract
    units, so it takes both.  Missing or ``null`` values are zero.

    Raises
    ------
    ResultError
        The file is missing, not JSON or has no ``radars`` object.
    """
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ResultError("no such file", path=path) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ResultError(f"cannot read as JSON: {exc}", path=path) from None
    radars = data.get("radars") if isinstance(data, Mapping) else None
    if not isinstance(radars, Mapping):
        raise ResultError("missing or not an object", path=path, field="radars")
    covariance = data.get("covariance")
    if isinstance(covariance, Mapping) and covariance.get("labels"):
        # A calibration result with its covariance: every check of from_dict.  Without
        # labels (a truth.json, values only) the values are checked below.
        Calibration.from_dict(data, source=path)
    out: dict[str, RadarBias] = {}
    for rid, entry in radars.items():
        if not isinstance(entry, Mapping):
            raise ResultError("not an object", path=path, field=f"radars.{rid}")
        values = {name: 0.0 for name in (*PARAMETER_NAMES, "time_offset", *ECCENTRICITY_NAMES)}
        fixed = entry.get("fixed") or {}
        items = list(fixed.items()) if isinstance(fixed, Mapping) else []
        items += [(k, v) for k, v in entry.items() if k in NAME_FROM_KEY]
        for key, value in items:
            if key not in NAME_FROM_KEY or value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ResultError(f"{value!r} is not a number", path=path,
                                  field=f"radars.{rid}.{key}")
            problem = bias_value_problem(key, float(value))
            if problem is not None:
                raise ResultError(problem, path=path, field=f"radars.{rid}.{key}")
            name = NAME_FROM_KEY[key]
            values[name] = float(value) / CONTRACT_KEYS[name][1]
        out[str(rid)] = RadarBias(
            values["range_offset"], values["range_gain"], values["azimuth_bias"],
            values["elevation_bias"], values["time_offset"],
            azimuth_sin_rad=values["azimuth_sin"], azimuth_cos_rad=values["azimuth_cos"],
        )
    return out
