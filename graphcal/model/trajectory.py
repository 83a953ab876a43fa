"""The trajectory formulation: every aircraft's path estimated with the biases, then eliminated.

Every aircraft (``target_id``) seen by two radars, or by a radar and ADS-B, gets a
path: a cubic B-spline in the network's frame with a white-acceleration prior
(:mod:`graphcal.model.paths`).  Then

* every radar plot is a measurement of the path at its own time in its radar's own
  coordinates, through the radar's measurement model (:mod:`graphcal.model.measurement`:
  refraction, the bias model with azimuth eccentricity, the time offset
  ``time_reported = time_true + time_offset_s``)::

      z = h_r(x(t_reported - tau_r), beta_r) + noise,     noise ~ N(0, diag(sigma_r^2))

  with no interpolation, no Cartesian conversion of noisy plots, no pairs;
* a 2-D radar's plot also carries its reported height (Mode C), a measurement of the
  path's ellipsoidal height ``h`` with 1-sigma :data:`ALTITUDE_SIGMA_M`; a pressure
  altitude is predicted from the path through the inverse height model,
  ``p = (h - d) / (1 + k)``;
* every ADS-B report is a measurement of the path at its own time, with its own
  sigma (``sigma_m`` horizontally, 1.5 times vertically); reports beyond a
  chi-square gate of the first fit are left out;
* the process noise ``q`` of the motion prior is estimated per flight phase
  (:data:`PHASE_S` of one path) by maximising the marginal likelihood of the data
  over :data:`PROCESS_NOISE_GRID_M2_S3`, so manoeuvres do not bias the biases; the
  heights have their own per vertical phase (:data:`VERTICAL_PHASE_S`), so that a
  levelling-off is not smoothed into the height model.

:class:`TrajectoryBlock` is one factor over the bias variables: at each value of the
biases it eliminates the paths exactly (one banded Cholesky for all paths; the
Schur complement of the bias columns), and hands GTSAM the reduced cost, gradient
and Gauss-Newton information as a whitened error ``e`` and Jacobian ``J`` with
``J^T J = S``, ``J^T e = g`` and ``|e|^2 / 2`` the reduced cost (GTSAM's smart
factors eliminate their landmarks the same way).  Every measurement goes through the
robust kernel.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.rows import take_rows
from graphcal.data.align import (
    ADSB_VERTICAL_SIGMA_RATIO,
    AdsbTrackTable,
    PlotArrays,
    adsb_track_table,
    plot_arrays,
)
from graphcal.data.bias import correct_bias
from graphcal.data.dataset import Dataset, Site
from graphcal.model import path_kernels
from graphcal.model.cross_radar import ALTITUDE_SIGMA_M, MAX_2D_ELEVATION_RAD
from graphcal.model.measurement import measurement_model
from graphcal.model.parameters import TERM_NAMES, RadarTerms
from graphcal.model.paths import (
    HALF_BANDWIDTH,
    BandFactor,
    PathLayout,
    add_measurement_blocks,
    add_motion_prior,
    band_matvec,
    band_to_dense,
    band_zeros,
    basis,
    basis_derivative,
    check_factorised,
    evaluate_paths,
    motion_prior_energy,
    scatter_columns,
    scatter_vectors,
    weighted_squares,
)
from graphcal.model.robust import RobustKernel

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Progress = Callable[..., None]

#: Knot spacing of the paths [s].  A cubic spline with knots 10 s apart follows a
#: 3 deg/s turn at 250 m/s to within 1 m (the error of the spline is about
#: ``spacing^4 |x''''| / 384``), far below any radar's noise.
KNOT_SPACING_S = 10.0
#: A path is cut where its aircraft is not seen by any radar for this long [s].
PATH_SPLIT_GAP_S = 120.0
#: ADS-B reports up to this long [s] before the first or after the last plot of a path
#: are kept on it.
ADSB_MARGIN_S = 30.0
#: Length [s] of a flight phase: the process noise is estimated per phase.
PHASE_S = 300.0
#: Length [s] of a vertical phase: the heights' own process noise is estimated per
#: vertical phase, shorter than a flight phase because an aircraft levels off or starts
#: a climb within seconds (:meth:`TrajectoryBlock._estimate_vertical_process_noise`).
VERTICAL_PHASE_S = 60.0
#: The process noises [m^2/s^3] among which each phase's is chosen (a level airliner
#: needs about 0.1, a turning one 10 or more).
PROCESS_NOISE_GRID_M2_S3 = tuple(float(v) for v in 10.0 ** np.arange(-2.0, 3.01, 0.5))
#: Process noise [m^2/s^3] of the first fit, before the phases' own are estimated.
INITIAL_PROCESS_NOISE_M2_S3 = 10.0
#: ADS-B reports whose whitened residual in the first fit exceeds this [sigma] are
#: left out (the 99.99 % point of a chi with 3 degrees of freedom is 4.9).
ADSB_GATE_SIGMA = 5.0
#: Robust refits of the first fit before the ADS-B gate (:func:`_gate_adsb`), done
#: only while some report is beyond :data:`ADSB_GROSS_SIGMA` [sigma].
ADSB_GATE_ITERATIONS = 3
ADSB_GROSS_SIGMA = 20.0
#: A path step decreasing the cost by more than this [chi2 units] is followed by another
#: before the reduced system is formed.
PATH_STEP_TOLERANCE = 0.5
#: Relative ridge added to the paths' normal matrix (numerical only).
RIDGE = 1e-12
#: Random draws of the paths' uncertainty from which the residuals' degrees of freedom
#: are estimated (:meth:`TrajectoryBlock.residual_fit`).
FIT_PROBES = 16
#: A whitened residual counts at most this [sigma] in the residuals' chi-square on the
#: paths (:meth:`TrajectoryBlock.residual_fit`).
FIT_CAP_SIGMA = 5.0
#: The plots' coordinates, in the order of their whitened residuals.
FIT_COORDINATES = ("range", "azimuth", "elevation")


@dataclass(frozen=True)
class NetworkFrame:
    """ENU frame at the network's centre (mean site latitude and longitude, height 0)."""

    lat_rad: float
    lon_rad: float

    @classmethod
    def of(cls, sites: list[Site]) -> NetworkFrame:
        return cls(float(np.mean([s.lat_rad for s in sites])),
                   float(np.mean([s.lon_rad for s in sites])))

    @property
    def origin_ecef_m(self) -> FloatArray:
        return frames.geodetic_to_ecef(self.lat_rad, self.lon_rad, 0.0)

    @property
    def rotation(self) -> FloatArray:
        """ECEF -> network ENU."""
        return frames.ecef_to_enu_rotation(self.lat_rad, self.lon_rad)

    def from_ecef(self, ecef_m: FloatArray) -> FloatArray:
        return frames.rotate(np.asarray(ecef_m) - self.origin_ecef_m, self.rotation)

    def to_ecef(self, enu_m: FloatArray) -> FloatArray:
        return frames.rotate(enu_m, self.rotation.T) + self.origin_ecef_m

    def heights_and_up(self, enu_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Ellipsoidal heights [m] and local verticals (unit, this frame) of points (in
        one compiled pass when the compiled loops are used: the same values)."""
        if path_kernels.enabled():
            return path_kernels.compiled().heights_and_up(
                np.ascontiguousarray(enu_m, dtype=float), self.rotation, self.origin_ecef_m)
        h, up_ecef = frames.ecef_to_height_and_normal(self.to_ecef(enu_m))
        return h, frames.rotate(up_ecef, self.rotation)

    def radar_map(self, site: Site) -> tuple[FloatArray, FloatArray]:
        """``(A, c)`` with radar ENU = ``A p + c`` for a network-ENU point ``p``."""
        a = site.ecef_to_enu @ self.rotation.T
        c = site.ecef_to_enu @ (self.origin_ecef_m - site.ecef_m)
        return a, c


# --------------------------------------------------------------------------- data on paths
@dataclass
class RadarOnPaths:
    """One radar's plots on the paths (fixed data)."""

    radar_id: str
    site: Site
    terms: RadarTerms
    rows: IntArray  # plot table index
    path: IntArray
    time_s: FloatArray  # reported
    measured: FloatArray  # (n, 3): range, azimuth, elevation (NaN for 2-D)
    altitude_m: FloatArray  # (n,) reported height, NaN where none (2-D only)
    map_a: FloatArray
    map_c: FloatArray

    @property
    def ndim(self) -> int:
        return 3 if self.site.is_3d else 2


@dataclass
class AdsbOnPaths:
    """ADS-B reports on the paths: constant contributions to the normal equations."""

    path: IntArray
    time_s: FloatArray
    position: FloatArray  # (n, 3) network frame
    information: FloatArray  # (n, 3, 3)
    first: IntArray
    weights: FloatArray
    interval: IntArray
    band: FloatArray  # their share of the paths' normal matrix
    rhs: FloatArray  # sum B kron W z
    constant: float  # 0.5 sum z^T W z


@dataclass
class _Group:
    """One set of linearised measurements: ``e + Hx dx + Hb db`` (whitened)."""

    radar_id: str
    kind: str  # "plots" or "heights"
    first: IntArray
    weights: FloatArray
    interval: IntArray
    hx: FloatArray  # (n, m, 3)
    hb: FloatArray  # (n, m, k)
    columns: IntArray  # (k,)
    e: FloatArray  # (n, m)


@dataclass
class _Linear:
    """The paths' normal equations at one linearisation."""

    band: FloatArray
    gradient: FloatArray
    cost: float
    groups: list[_Group]
    phase_cost: FloatArray | None = None  # (n_phases,): the data's cost by flight phase
    cross: FloatArray | None = None  # (n_unknowns, P): the first P columns of ``stacked``
    stacked: FloatArray | None = None  # (n_unknowns, P + 1): cross, then room for the gradient
    bias_information: FloatArray | None = None
    bias_gradient: FloatArray | None = None


# --------------------------------------------------------------------------- the block
@dataclass
class TrajectoryBlock:
    """All paths and every measurement of them: one factor on the bias variables."""

    frame: NetworkFrame
    layout: PathLayout
    radars: list[RadarOnPaths]
    adsb: AdsbOnPaths | None
    kernel: RobustKernel
    #: Variables of the factor, in order: (key, radar id or "" for the height model, size).
    variables: list[tuple[int, str, int]]
    height_key: int | None
    pressure: bool
    coefficients: FloatArray  # (n_coefficients, 3): the current paths
    phase_scale: FloatArray  # (n_phases,): 1 / q
    vertical_scale: FloatArray  # (n_vertical_phases,): 1 / q of the heights
    n_aircraft: int
    target_of_path: NDArray[np.object_]
    fixed_values: dict[str, FloatArray] = field(default_factory=dict)
    n_adsb_gated: int = 0
    last_weights: dict[str, FloatArray] = field(default_factory=dict)
    n_calls: int = 0
    _prior_cache: tuple[FloatArray, FloatArray] | None = field(default=None, repr=False)
    _reduced_cache: tuple[tuple[bytes, bytes], tuple] | None = field(default=None, repr=False)
    #: The last elimination's biases (flat), ``L^-1 X`` and the paths' factor ``L``: the
    #: paths' first-order response to a change of the biases (:meth:`_follow_biases`).
    _path_response: tuple[FloatArray, FloatArray, BandFactor] | None = field(
        default=None, repr=False)

    # ------------------------------------------------------------ layout of the biases
    @property
    def keys(self) -> list[int]:
        return [key for key, _, _ in self.variables]

    @property
    def n_bias(self) -> int:
        return sum(size for _, _, size in self.variables)

    @property
    def radars_seen(self) -> set[str]:
        return {r.radar_id for r in self.radars}

    def _columns(self) -> dict[str, IntArray]:
        out, start = {}, 0
        for _, name, size in self.variables:
            out[name] = np.arange(start, start + size)
            start += size
        return out

    def with_terms(self, terms: dict[str, RadarTerms], variable_radars: list[str]
                   ) -> TrajectoryBlock:
        """The same paths and measurements with other free terms (e.g. without the time
        offsets the data do not determine): the paths and process noise carry over."""
        radars = [dataclasses.replace(r, terms=terms[r.radar_id]) for r in self.radars]
        variables = [(key, name, 2 if not name else len(terms[name].free))
                     for key, name, _ in self.variables
                     if not name or (name in variable_radars and terms[name].free)]
        names = {name for _, name, _ in variables}
        fixed = {r.radar_id: np.zeros(0) for r in radars if r.radar_id not in names}
        return dataclasses.replace(self, radars=radars, variables=variables,
                                   fixed_values=fixed, last_weights={}, n_calls=0,
                                   _reduced_cache=None, _path_response=None)

    def values_of(self, named: dict[str, FloatArray]) -> list[FloatArray]:
        """The factor's variable values in order, from a dict by radar id (``""``: the
        height model)."""
        return [np.asarray(named.get(name, np.zeros(size)), dtype=float)
                for _, name, size in self.variables]

    def _split(self, values: list[FloatArray]) -> dict[str, FloatArray]:
        named = {name: np.asarray(v, dtype=float)
                 for (_, name, _), v in zip(self.variables, values, strict=True)}
        for rid, v in self.fixed_values.items():
            named.setdefault(rid, v)
        return named

    @property
    def dimension(self) -> int:
        """Measurement dimensions minus the paths' effective unknowns (for chi2/dof)."""
        n = sum(len(r.rows) * r.ndim + int(np.isfinite(r.altitude_m).sum())
                for r in self.radars)
        n += 0 if self.adsb is None else 3 * len(self.adsb.time_s)
        return int(n - 6 * self.layout.n_paths)

    # ------------------------------------------------------------ linearisation
    def _linearise(self, named: dict[str, FloatArray], want_bias: bool,
                   coefficients: FloatArray | None = None,
                   estimate_process_noise: bool = False) -> _Linear:
        """The normal equations of paths and biases at these biases and paths; with
        ``estimate_process_noise``, the phases' process noise is first estimated from
        the data's share (:meth:`_estimate_process_noise`) and the prior is then that
        of the new noise."""
        c = self.coefficients if coefficients is None else coefficients
        lin = self._linearise_data(named, want_bias, c)
        if estimate_process_noise:
            self._estimate_process_noise(lin, c)
        self._add_prior(lin, c)
        return lin

    def _add_prior(self, lin: _Linear, c: FloatArray) -> None:
        """Add the motion prior ``Omega / q`` to linearised data, in place."""
        cached = self._prior_cache
        scales = np.concatenate([self.phase_scale, self.vertical_scale])
        if cached is not None and np.array_equal(cached[0], scales):
            prior_band = cached[1]
        else:
            prior_band = band_zeros(self.layout.n_unknowns)
            add_motion_prior(prior_band, self.layout, self.phase_scale, self.vertical_scale)
            self._prior_cache = (scales, prior_band)
        flat = c.ravel()
        prior_gradient = band_matvec(prior_band, flat)
        lin.band += prior_band
        lin.band[0] += RIDGE * np.maximum(lin.band[0].max(initial=1.0), 1.0)
        lin.gradient += prior_gradient
        lin.cost += 0.5 * float(flat @ prior_gradient)

    def _noise_key(self) -> bytes:
        """The process noises as bytes (what a reduced system was formed with)."""
        return self.phase_scale.tobytes() + self.vertical_scale.tobytes()

    def _linearise_data(self, named: dict[str, FloatArray], want_bias: bool,
                        c: FloatArray) -> _Linear:
        """The measurements' share of the normal equations (no motion prior)."""
        layout = self.layout
        n = layout.n_unknowns
        columns = self._columns()
        band = band_zeros(n)
        flat = c.ravel()
        gradient = np.zeros(n)
        cost = 0.0
        if self.adsb is not None:
            band += self.adsb.band
            adsb_ax = band_matvec(self.adsb.band, flat)
            gradient += adsb_ax - self.adsb.rhs
            cost += 0.5 * float(flat @ adsb_ax) - float(flat @ self.adsb.rhs) + self.adsb.constant
        # The plots' cost by phase; the ADS-B reports' share is added when the process
        # noise is estimated (_adsb_phase_cost), not at every linearisation.
        phase_cost = np.zeros(layout.n_phases)
        groups = []
        height = named.get("") if self.pressure else None
        for radar in self.radars:
            groups.extend(self._radar_groups(radar, named.get(radar.radar_id, np.zeros(0)),
                                             height, c, columns))
        p = self.n_bias
        lin = _Linear(band, gradient, cost, groups, phase_cost=phase_cost)
        if want_bias:
            lin.stacked = np.zeros((n, p + 1))
            lin.cross = lin.stacked[:, :p]
            lin.bias_information = np.zeros((p, p))
            lin.bias_gradient = np.zeros(p)
        if path_kernels.enabled():
            self._accumulate_compiled(lin, groups, want_bias)
            return lin
        firsts, weights, infos, gradients = [], [], [], []
        pending: dict[str, list[tuple[IntArray, FloatArray, FloatArray, IntArray]]] = {}
        for g in groups:
            w = self._robust_weights(lin, g)
            weighted = g.hx * w[:, None, None]
            infos.append(np.swapaxes(weighted, 1, 2) @ g.hx)
            gradients.append(np.einsum("nmi,nm->ni", weighted, g.e))
            firsts.append(g.first)
            weights.append(g.weights)
            if want_bias and len(g.columns):
                assert lin.bias_information is not None and lin.bias_gradient is not None
                weighted_hb = g.hb * w[:, None, None]
                pending.setdefault(g.radar_id, []).append(
                    (g.first, g.weights, np.swapaxes(weighted, 1, 2) @ g.hb, g.columns))
                lin.bias_information[np.ix_(g.columns, g.columns)] += np.einsum(
                    "nmk,nml->kl", weighted_hb, g.hb)
                lin.bias_gradient[g.columns] += np.einsum("nmk,nm->k", weighted_hb, g.e)
        for parts in pending.values():  # one scatter per radar, over its columns
            assert lin.cross is not None
            columns_all = np.unique(np.concatenate([cols for *_, cols in parts]))
            blocks = []
            for _, _, block, cols in parts:
                padded = np.zeros((len(block), 3, len(columns_all)))
                padded[:, :, np.searchsorted(columns_all, cols)] = block
                blocks.append(padded)
            scatter_columns(np.concatenate([f for f, *_ in parts]),
                            np.concatenate([wt for _, wt, *_ in parts]),
                            np.concatenate(blocks), columns_all, lin.cross)
        if groups:
            first_all, weights_all = np.concatenate(firsts), np.concatenate(weights)
            add_measurement_blocks(lin.band, first_all, weights_all, np.concatenate(infos))
            lin.gradient += scatter_vectors(first_all, weights_all, np.concatenate(gradients), n)
        return lin

    def _robust_weights(self, lin: _Linear, g: _Group) -> FloatArray:
        """The group's robust weights; its robust cost added to ``lin`` (in all and by
        flight phase)."""
        assert lin.phase_cost is not None
        m = g.e.shape[1]
        s = frames.row_norm(g.e)
        loss = self.kernel.loss(s, m)
        lin.cost += float(np.sum(loss))
        lin.phase_cost += np.bincount(self.layout.phase[g.interval], loss,
                                      minlength=self.layout.n_phases)
        return self.kernel.weight(s, m)

    def _accumulate_compiled(self, lin: _Linear, groups: list[_Group], want_bias: bool) -> None:
        """The groups' sums into ``lin`` with the compiled loops (:mod:`path_kernels`):
        the same sums as NumPy's in :meth:`_linearise_data`, one pass per group."""
        loops = path_kernels.compiled()
        if want_bias:
            assert lin.cross is not None and lin.bias_information is not None
            assert lin.bias_gradient is not None
            cross, information, gradient = lin.cross, lin.bias_information, lin.bias_gradient
        else:
            cross, information, gradient = np.zeros((1, 0)), np.zeros((0, 0)), np.zeros(0)
        for g in groups:
            w = self._robust_weights(lin, g)
            columns = (g.columns if want_bias else np.zeros(0, dtype=np.int64))
            hb = g.hb if want_bias else g.hb[:, :, :0]
            loops.accumulate(lin.band, lin.gradient, cross, information, gradient,
                             np.ascontiguousarray(g.first, dtype=np.int64),
                             np.ascontiguousarray(g.weights), np.ascontiguousarray(g.hx),
                             np.ascontiguousarray(hb), np.ascontiguousarray(g.e),
                             np.ascontiguousarray(w, dtype=float),
                             np.ascontiguousarray(columns, dtype=np.int64))

    def _radar_groups(self, radar: RadarOnPaths, free: FloatArray, height: FloatArray | None,
                      c: FloatArray, columns: dict[str, IntArray]) -> list[_Group]:
        terms = radar.terms
        full = terms.full_terms(free)
        tau = full[4]
        first, u, interval = self._locate(radar.path, radar.time_s - tau)
        weights = basis(u)
        free_names = terms.free
        rates = (_basis_rate(u, self.layout.spacing_s) if "time_offset" in free_names
                 else None)
        compiled = path_kernels.enabled() and compiled_plot_model(radar, full)
        linearise = plots_on_paths_compiled if compiled else plots_on_paths
        e, hx, hb, position, velocity = linearise(radar, c, first, weights, rates, full)
        cols = columns.get(radar.radar_id, np.zeros(0, dtype=np.int64))
        if len(cols) == 0:
            hb = hb[:, :, :0]
        groups = [_Group(radar.radar_id, "plots", first, weights, interval, hx, hb, cols, e)]
        if radar.site.is_3d:
            return groups
        has = np.isfinite(radar.altitude_m)
        if not np.any(has):
            return groups
        # The reported height: a measurement of the path's ellipsoidal height.
        h, up = self.frame.heights_and_up(take_rows(position, has))
        reported = radar.altitude_m[has]
        height_cols = np.zeros(0, dtype=np.int64)
        # The reported altitude is predicted from the path in its own terms: a pressure
        # altitude p = (h - d) / (1 + k) through the inverse height model.  (Written the
        # other way round, h - ((1 + k) p + d), the noisy p would multiply k: its noise
        # in both the residual and the Jacobian biases k, errors in variables.)
        scale = 1.0
        if height is not None:
            scale = 1.0 + float(height[1])
            predicted = (h - height[0]) / scale
            height_cols = columns[""]
        else:
            predicted = h
        per_metre = 1.0 / (scale * ALTITUDE_SIGMA_M)  # whitened error per metre of height
        e_h = ((predicted - reported) / ALTITUDE_SIGMA_M)[:, None]
        hx_h = (up * per_metre)[:, None, :]
        blocks = []
        if len(cols) and velocity is not None:
            # Of the radar's terms only the time offset moves the reported height.
            k = free_names.index("time_offset")
            hb_tau = -np.einsum("ni,ni->n", up, take_rows(velocity, has)) * per_metre
            blocks.append((hb_tau[:, None, None], cols[k:k + 1]))
        if len(height_cols):
            hb_model = -np.stack([np.ones_like(predicted), predicted], axis=-1)[:, None, :]
            blocks.append((hb_model * per_metre, height_cols))
        hb_all = (np.concatenate([b for b, _ in blocks], axis=2) if blocks
                  else np.zeros((len(e_h), 1, 0)))
        cols_all = (np.concatenate([cc for _, cc in blocks]) if blocks
                    else np.zeros(0, dtype=np.int64))
        groups.append(_Group(radar.radar_id, "heights", first[has], take_rows(weights, has),
                             interval[has], hx_h, hb_all, cols_all, e_h))
        return groups

    def _locate(self, path: IntArray, time_s: FloatArray) -> tuple[IntArray, FloatArray, IntArray]:
        first, u = self.layout.locate(path, time_s)
        interval_offset = np.concatenate([[0], np.cumsum(self.layout.n_intervals)[:-1]])
        interval = interval_offset[path] + (first - self.layout.first_coefficient[path])
        return first, u, interval

    # ------------------------------------------------------------ elimination
    def _settle_paths(self, named: dict[str, FloatArray], max_steps: int) -> None:
        """Gauss-Newton steps of the paths at fixed biases."""
        self._reduced_cache = self._path_response = None
        for _ in range(max_steps):
            lin = self._linearise(named, want_bias=False)
            factor = BandFactor.of(lin.band)
            z = factor.forward(lin.gradient)
            step = factor.backward(z)
            self.coefficients = self.coefficients - step.reshape(-1, 3)
            if 0.5 * float(z @ z) < PATH_STEP_TOLERANCE:
                break

    def reduced(self, values: list[FloatArray], want: bool,
                estimate_process_noise: bool = False
                ) -> tuple[float, FloatArray | None, FloatArray | None]:
        """The reduced cost, gradient and information on the biases (paths eliminated).

        The joint system is linearised at these biases and the current paths (those the
        last call left); the reduced quantities are those of its Gauss-Newton model with
        the paths re-optimised in it: ``cost - |L^-1 g_x|^2 / 2``, ``g_b - X^T A^-1 g_x``
        and ``A_bb - X^T A^-1 X`` (exact for the paths' share of the cost to second order;
        the paths' measurement model is nearly linear).  The paths then take that step,
        the start of the next call.  ``want`` is accepted for symmetry: the bias columns
        are always formed, and the last call's result is served again for the same
        biases.  With ``estimate_process_noise`` the phases' process noise is first
        estimated at this linearisation (:meth:`_estimate_process_noise`), and the
        reduced system is that of the new noise.
        """
        flat = np.concatenate([np.ravel(v) for v in values] or [np.zeros(0)]).astype(float)
        if (not estimate_process_noise and self._reduced_cache is not None
                and self._reduced_cache[0] == (flat.tobytes(), self._noise_key())):
            return self._reduced_cache[1]
        self.n_calls += 1
        self._follow_biases(flat)
        named = self._split(values)
        # Always with the bias columns: GTSAM asks for the error at a point and then,
        # when it accepts the point, for its linearisation there (served from the cache).
        lin = self._linearise(named, want_bias=True,
                              estimate_process_noise=estimate_process_noise)
        factor = BandFactor.of(lin.band)
        assert lin.cross is not None and lin.bias_information is not None
        assert lin.bias_gradient is not None
        assert lin.stacked is not None
        lin.stacked[:, -1] = lin.gradient
        stacked = factor.forward(lin.stacked, overwrite=True)
        zx, zg = stacked[:, :-1], np.ascontiguousarray(stacked[:, -1])
        information = lin.bias_information - zx.T @ zx
        gradient = lin.bias_gradient - zx.T @ zg
        cost = lin.cost - 0.5 * float(zg @ zg)
        # The paths move to their optimum at these biases (the step the reduced system
        # assumes), the start of the next call.
        self.coefficients = self.coefficients - factor.backward(zg).reshape(-1, 3)
        self._path_response = (flat, zx, factor)
        self._record_weights(lin)
        out = (cost, gradient, 0.5 * (information + information.T))
        # Keyed by the noise the system was reduced with (estimate_process_noise sets it).
        self._reduced_cache = ((flat.tobytes(), self._noise_key()), out)
        return out

    def _follow_biases(self, flat: FloatArray) -> None:
        """Move the paths with the biases' change since the last elimination.

        That elimination left the paths at their optimum for its biases ``b0``; at biases
        ``b`` the joint Gauss-Newton step moves them further by ``-A^-1 X (b - b0)``
        (``L^-T (L^-1 X) (b - b0)`` with its factor): the paths follow the biases, as a
        bundle adjustment back-substitutes its points, so that the next linearisation is
        at the joint iterate rather than at paths fitted to the old biases.
        """
        response = self._path_response
        if response is None or len(response[0]) != len(flat):
            return
        previous, zx, factor = response
        change = flat - previous
        if np.any(change != 0.0):
            self.coefficients = self.coefficients - factor.backward(zx @ change).reshape(-1, 3)

    def normal_equations(self, values: list[FloatArray]) -> dict[str, FloatArray]:
        """The joint Gauss-Newton normal equations of paths and biases at the current
        paths (dense; for checks on small problems): ``information`` over
        ``[path unknowns, biases]``, ``gradient`` and ``cost``."""
        lin = self._linearise(self._split(values), want_bias=True)
        assert lin.cross is not None and lin.bias_information is not None
        assert lin.bias_gradient is not None
        information = np.block([[band_to_dense(lin.band), lin.cross],
                                [lin.cross.T, lin.bias_information]])
        return {"information": information,
                "gradient": np.concatenate([lin.gradient, lin.bias_gradient]),
                "cost": np.array(lin.cost)}

    def settle(self, values: list[FloatArray], steps: int) -> None:
        """Move the paths towards their optimum at fixed biases (Gauss-Newton steps)."""
        self._settle_paths(self._split(values), steps)

    def error(self, values: list[FloatArray], want: bool
              ) -> tuple[FloatArray, list[FloatArray] | None]:
        """Whitened error and Jacobians for GTSAM (module docstring)."""
        cost, gradient, information = self.reduced(values, want)
        p = self.n_bias
        cost = max(cost, 0.0)
        if not want:
            e = np.zeros(p + 1)
            e[-1] = np.sqrt(2.0 * cost)
            return e, None
        assert gradient is not None and information is not None
        # A square root of the information, in units scaled to its diagonal (terms in
        # metres and radians differ by ten orders of magnitude).
        scale = np.sqrt(np.maximum(np.diag(information), 1e-300))
        eigenvalues, vectors = np.linalg.eigh(information / np.outer(scale, scale))
        keep = eigenvalues > 1e-12 * max(eigenvalues.max(initial=0.0), 1e-300)
        root = np.sqrt(np.where(keep, eigenvalues, 0.0))
        jacobian = np.zeros((p + 1, p))
        jacobian[:p] = (root[:, None] * vectors.T) * scale[None, :]
        e = np.zeros(p + 1)
        projected = vectors.T @ (gradient / scale)
        e[:p] = np.where(keep, projected / np.where(keep, root, 1.0), 0.0)
        e[p] = np.sqrt(max(2.0 * cost - float(e[:p] @ e[:p]), 0.0))
        blocks, start = [], 0
        for _, _, size in self.variables:
            blocks.append(jacobian[:, start:start + size])
            start += size
        return e, blocks

    def _record_weights(self, lin: _Linear) -> None:
        weights: dict[str, list[FloatArray]] = {}
        for g in lin.groups:
            if g.kind != "plots":
                continue
            s = frames.row_norm(g.e)
            weights.setdefault(g.radar_id, []).append(self.kernel.weight(s, g.e.shape[1]))
        self.last_weights = {rid: np.concatenate(w) for rid, w in weights.items()}

    # ------------------------------------------------------------ process noise
    def _estimate_process_noise(self, lin: _Linear, coefficients: FloatArray) -> FloatArray:
        """Each phase's process noise [m^2/s^3] by maximum marginal likelihood (grid),
        then the heights' own (:meth:`_estimate_vertical_process_noise`).

        For each ``q`` of :data:`PROCESS_NOISE_GRID_M2_S3` the paths' Laplace
        log-likelihood is split by phase (:func:`_most_likely_process_noise`; the motion
        prior's rank is ``3 (K + 1)`` on a path of ``K`` intervals); every phase takes the
        ``q`` that maximises its share.  Sets both and returns the phases' ``q``.

        ``lin`` is the data's share of a linearisation at the paths ``coefficients``,
        before the motion prior is added (:meth:`_linearise`).
        """
        assert lin.phase_cost is not None
        layout = self.layout
        energy_by_axis = motion_prior_energy(coefficients, layout, per_axis=True)
        # The prior of q = 1 (every phase alike on the grid), scaled for each q.
        unit_prior = band_zeros(layout.n_unknowns)
        add_motion_prior(unit_prior, layout, np.ones(layout.n_phases))
        unit_gradient = band_matvec(unit_prior, coefficients.ravel())
        chosen = _most_likely_process_noise(
            lin.band, lin.gradient, unit_prior, unit_gradient, layout,
            energy_by_axis.sum(axis=1), lin.phase_cost + self._adsb_phase_cost(coefficients))
        self.phase_scale = 1.0 / chosen
        self.vertical_scale = 1.0 / self._estimate_vertical_process_noise(
            lin.band, lin.gradient, unit_prior, unit_gradient, energy_by_axis[:, 2])
        return chosen

    def _estimate_vertical_process_noise(self, data_band: FloatArray, data_gradient: FloatArray,
                                         unit_prior: FloatArray, unit_gradient: FloatArray,
                                         vertical_energy: FloatArray) -> FloatArray:
        """Each vertical phase's process noise of the heights [m^2/s^3] (grid, maximum
        likelihood).

        An aircraft levelling off or starting a climb changes its vertical rate in
        seconds, while it turns for minutes: one ``q`` for all axes over five minutes
        smooths the corners of its height profile, and the paths sit below the truth at
        the tops of climbs and above it at their feet, a compression of heights that the
        height model's scale then absorbs.  The heights get their own ``q`` per vertical
        phase (:data:`VERTICAL_PHASE_S`), chosen as the others are on the vertical
        unknowns alone (the horizontal held at their paths: the axes are nearly
        uncoupled).  ``unit_prior`` and ``unit_gradient``: the prior of ``q = 1`` on every
        axis and its gradient at the paths; ``vertical_energy``: the paths' vertical
        ``int z''^2 dt`` by interval [m^2/s^3].
        """
        up = slice(2, None, 3)  # the vertical unknowns; their band is every third row
        rows = slice(0, HALF_BANDWIDTH + 1, 3)
        return _most_likely_process_noise(
            np.ascontiguousarray(data_band[rows, up]), data_gradient[up],
            np.ascontiguousarray(unit_prior[rows, up]), unit_gradient[up], self.layout,
            vertical_energy, None, vertical=True)

    def _adsb_phase_cost(self, c: FloatArray) -> FloatArray:
        """The ADS-B reports' cost ``chi2 / 2`` by flight phase, on paths ``c``."""
        layout = self.layout
        if self.adsb is None:
            return np.zeros(layout.n_phases)
        a = self.adsb
        chi2 = weighted_squares(c, a.first, a.weights, a.position, a.information)
        return np.bincount(layout.phase[a.interval], 0.5 * chi2, minlength=layout.n_phases)

    # ------------------------------------------------------------ reporting
    def summary(self) -> dict:
        q = 1.0 / self.phase_scale
        q_up = 1.0 / self.vertical_scale
        return {
            "formulation": "trajectory",
            "n_aircraft": self.n_aircraft,
            "n_paths": self.layout.n_paths,
            "n_path_unknowns": self.layout.n_unknowns,
            "knot_spacing_s": self.layout.spacing_s,
            "n_phases": self.layout.n_phases,
            "process_noise_m2_s3": {
                "median": float(np.median(q)), "p90": float(np.percentile(q, 90)),
                "max": float(q.max()),
            },
            "vertical_process_noise_m2_s3": {
                "median": float(np.median(q_up)), "p90": float(np.percentile(q_up, 90)),
                "max": float(q_up.max()),
            },
            "n_adsb_reports": 0 if self.adsb is None else int(len(self.adsb.time_s)),
            "n_adsb_gated": self.n_adsb_gated,
            "n_plots": self.plots_per_radar(),
            "n_eliminations": self.n_calls,
        }

    def residual_fit(self, values: list[FloatArray], n_probes: int = FIT_PROBES,
                     rng: np.random.Generator | None = None
                     ) -> dict[str, dict[str, dict[str, float | int]]]:
        """Each radar's residuals on the paths at the biases ``values``, by coordinate.

        The paths follow the biases from the last elimination (its Gauss-Newton response,
        :meth:`_follow_biases`); each plot's whitened residuals in range, azimuth and
        (3-D) elevation, and a 2-D plot's reported height (``altitude``), are summed into
        ``chi2``, each square capped at :data:`FIT_CAP_SIGMA` squared (a path that misses
        its aircraft for a few scans, which the robust kernel sets aside, would
        otherwise dominate the sum; the cap takes 1e-6 of a Gaussian residual's mean
        square, and a unit or frame error still gives ``chi2/dof`` near the cap's 25;
        ``n_beyond_cap`` counts the residuals capped).  A correct model with the stated
        noise gives ``chi2`` near its degrees of freedom ``n - paths_dof`` (less the
        radar's terms, which the caller counts): ``paths_dof`` is the share of the paths'
        unknowns the coordinate's measurements take, ``tr(A^-1 D)`` with ``A`` the paths'
        normal matrix (motion prior, every measurement and its robust weight) and ``D``
        the coordinate's own share of it.  Summed over every group, ADS-B and the prior
        it is the number of unknowns.

        ``tr(A^-1 D) = E[v^T D v]`` for ``v ~ N(0, A^-1)`` (``v = L^-T xi``, ``xi``
        standard normal): it is estimated from ``n_probes`` such draws of ``rng``
        (default: seeded with 0, the same figures on every run).  As ``A^-1 D`` has
        eigenvalues in ``[0, 1]``, the estimate's standard deviation is at most
        ``sqrt(2 tr / n_probes)``: about 11 of 1,000 degrees of freedom with 16 draws.

        Returns
        -------
        dict
            ``{radar_id: {coordinate: {"chi2", "n", "paths_dof", "n_beyond_cap"}}}``.
        """
        rng = np.random.default_rng(0) if rng is None else rng
        flat = np.concatenate([np.ravel(v) for v in values] or [np.zeros(0)]).astype(float)
        self._follow_biases(flat)
        lin = self._linearise(self._split(values), want_bias=False)
        factor = BandFactor.of(lin.band)
        draws = factor.backward(rng.standard_normal((self.layout.n_unknowns, n_probes)))
        draws = draws.reshape(-1, 3, n_probes)  # by coefficient, axis and draw
        out: dict[str, dict[str, dict[str, float | int]]] = {}
        for g in lin.groups:
            m = g.e.shape[1]
            names = ("altitude",) if g.kind == "heights" else FIT_COORDINATES[:m]
            w = self.kernel.weight(frames.row_norm(g.e), m)
            moved = g.weights[:, 0, None, None] * draws[g.first]  # (n, 3, draws)
            for j in range(1, 4):
                moved += g.weights[:, j, None, None] * draws[g.first + j]
            along = np.matmul(g.hx, moved)  # (n, m, draws)
            share = w @ np.einsum("nck,nck->nc", along, along)
            squares = g.e * g.e
            chi2 = np.sum(np.minimum(squares, FIT_CAP_SIGMA**2), axis=0)
            beyond = np.sum(squares > FIT_CAP_SIGMA**2, axis=0)
            radar = out.setdefault(g.radar_id, {})
            for c, name in enumerate(names):
                entry = radar.setdefault(name, {"chi2": 0.0, "n": 0, "paths_dof": 0.0,
                                                "n_beyond_cap": 0})
                entry["chi2"] += float(chi2[c])
                entry["n"] += len(g.e)
                entry["paths_dof"] += float(share[c] / n_probes)
                entry["n_beyond_cap"] += int(beyond[c])
        return out

    def n_pressure_plots(self) -> int:
        """2-D plots whose pressure altitude measures their path (through the height
        model); 0 without pressure altitudes."""
        if not self.pressure:
            return 0
        return int(sum(np.isfinite(r.altitude_m).sum() for r in self.radars
                       if not r.site.is_3d))

    def plots_per_radar(self) -> dict[str, int]:
        return {r.radar_id: int(len(r.rows)) for r in self.radars}

    def downweighted(self, bias_values: dict[str, FloatArray], result) -> dict[str, dict[str, int]]:
        """Plots with a final robust weight below 0.5, per radar."""
        del bias_values, result
        return {rid: {"plots": int(np.sum(w < 0.5))} for rid, w in self.last_weights.items()}

    def add_to(self, fg, variable: set[str], initial_free: dict) -> None:
        """Add the block to a :class:`~graphcal.solvers.gtsam_adapter.FactorGraph` (duck-typed)."""
        del variable, initial_free
        fg.add_custom(self.keys, self.n_bias + 1, self.error)


def _most_likely_process_noise(data_band: FloatArray, data_gradient: FloatArray,
                               unit_prior: FloatArray, unit_gradient: FloatArray,
                               layout: PathLayout, energy: FloatArray,
                               cost: FloatArray | None, vertical: bool = False) -> FloatArray:
    """The process noise [m^2/s^3] of :data:`PROCESS_NOISE_GRID_M2_S3` that maximises each
    phase's share of the paths' Laplace log-likelihood.

    For each ``q``, by phase: ``-(cost + E / (2 q) - |L^-1 g|^2 / 2) - sum log L_ii -
    rank / 2 log q``, with ``L`` the factor of ``data_band + unit_prior / q``, ``g`` the
    gradient ``data_gradient + unit_gradient / q`` and ``E`` the prior's ``int x''^2 dt``
    (``energy`` by interval).  The phases are ``layout``'s flight phases over the three
    axes, or with ``vertical`` its vertical phases over the vertical unknowns alone (the
    band's every third unknown); the prior's rank is ``axes (K + 1)`` on a path of ``K``
    intervals (straight motion is free: ``axes`` per interval, and ``axes`` more counted in
    the path's first phase); ``cost`` is the data's cost by phase (``None``: constant).
    """
    if vertical:
        phase, n_phases, axes = layout.vertical_phase, layout.n_vertical_phases, 1.0
        unknown_phase = layout.unknown_phase(vertical=True)[2::3]
    else:
        phase, n_phases, axes = layout.phase, layout.n_phases, 3.0
        unknown_phase = layout.unknown_phase()
    cost = np.zeros(n_phases) if cost is None else cost
    first_phase = phase[np.concatenate([[0], np.cumsum(layout.n_intervals)[:-1]])]
    rank = axes * (np.bincount(phase, minlength=n_phases)
                   + np.bincount(first_phase, minlength=n_phases))
    energy = np.bincount(phase, energy, minlength=n_phases)
    best = np.full(n_phases, -np.inf)
    chosen = np.full(n_phases, INITIAL_PROCESS_NOISE_M2_S3)
    for q in PROCESS_NOISE_GRID_M2_S3:
        reduction, log_det = noise_likelihood_terms(data_band, data_gradient, unit_prior,
                                                    unit_gradient, 1.0 / q, unknown_phase,
                                                    n_phases)
        log_lik = -(cost + 0.5 * energy / q - reduction) - log_det - 0.5 * rank * np.log(q)
        better = log_lik > best
        best = np.where(better, log_lik, best)
        chosen = np.where(better, q, chosen)
    return chosen


def noise_likelihood_terms(data_band: FloatArray, data_gradient: FloatArray,
                           unit_prior: FloatArray, unit_gradient: FloatArray, scale: float,
                           unknown_phase: IntArray, n_phases: int
                           ) -> tuple[FloatArray, FloatArray]:
    """Per phase, ``|L^-1 g|^2 / 2`` and ``sum log L_ii`` of the band ``data_band + scale
    unit_prior`` (raised by :data:`RIDGE` on its diagonal) and the gradient
    ``data_gradient + scale unit_gradient`` (:func:`_most_likely_process_noise`): in one
    compiled pass when the compiled loops are used, else by LAPACK."""
    if path_kernels.enabled():
        work = np.empty(data_band.shape, order="F")
        info, reduction, log_det = path_kernels.compiled().noise_likelihood_terms(
            np.asfortranarray(data_band), np.asfortranarray(unit_prior), float(scale),
            np.ascontiguousarray(data_gradient), np.ascontiguousarray(unit_gradient), RIDGE,
            np.ascontiguousarray(unknown_phase, dtype=np.int64), n_phases, work)
        check_factorised(info)
        return reduction, log_det
    band = unit_prior * scale + data_band
    band[0] += RIDGE * np.maximum(band[0].max(initial=1.0), 1.0)
    factor = BandFactor.of(band, overwrite=True)
    z = factor.forward(data_gradient + unit_gradient * scale)
    return (np.bincount(unknown_phase, 0.5 * z * z, minlength=n_phases),
            np.bincount(unknown_phase, factor.log_diagonal(), minlength=n_phases))


def plots_on_paths(radar: RadarOnPaths, c: FloatArray, first: IntArray, weights: FloatArray,
                   rates: FloatArray | None, full: FloatArray
                   ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray | None]:
    """A radar's plots linearised on the paths ``c``: the whitened residuals ``e``
    (n, m), ``hx`` (n, m, 3) and ``hb`` (n, m, free terms), the paths' positions (n, 3)
    and, with ``rates`` (the basis' rates, given when the time offset is free), their
    velocities (n, 3).  ``first``, ``weights``: where the plots fall on the paths;
    ``full``: every term of the radar's bias model."""
    free_names = radar.terms.free
    position = evaluate_paths(c, first, weights)
    enu = frames.rotate(position, radar.map_a) + radar.map_c
    predicted, d_enu, hb = measurement_model(radar.site).measure(enu, full, free_names)
    e = predicted - radar.measured
    e[:, 1] = frames.wrap_to_pi(e[:, 1])
    m = radar.ndim
    hx = d_enu[:, :m] @ radar.map_a
    hb = np.ascontiguousarray(hb[:, :m])
    velocity = None
    if rates is not None:
        k = free_names.index("time_offset")
        velocity = evaluate_paths(c, first, rates)
        hb[:, :, k] = -np.einsum("nmi,ni->nm", hx, velocity)
    whiten = 1.0 / radar.site.measurement_sigmas()[:m]
    hx *= whiten[None, :, None]
    hb *= whiten[None, :, None]
    return e[:, :m] * whiten[None, :], hx, hb, position, velocity


def compiled_plot_model(radar: RadarOnPaths, full: FloatArray) -> bool:
    """Whether :func:`plots_on_paths_compiled` forms this radar's model: no refraction,
    and no azimuth eccentricity (neither its value nor its terms free)."""
    return (radar.site.atmosphere is None and full[5] == 0.0 and full[6] == 0.0
            and all(name in _COMPILED_TERM_KINDS for name in radar.terms.free))


def plots_on_paths_compiled(radar: RadarOnPaths, c: FloatArray, first: IntArray,
                            weights: FloatArray, rates: FloatArray | None, full: FloatArray
                            ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray,
                                       FloatArray | None]:
    """:func:`plots_on_paths` in one compiled pass (:func:`graphcal.model.path_loops.
    plot_linearisation`), for a radar :func:`compiled_plot_model` accepts: the same values."""
    free_names = radar.terms.free
    kinds = np.array([_COMPILED_TERM_KINDS[name][0] for name in free_names], dtype=np.int64)
    rows = np.array([_COMPILED_TERM_KINDS[name][1] for name in free_names], dtype=np.int64)
    m = radar.ndim
    e, hx, hb, position, velocity, zenith = path_kernels.compiled().plot_linearisation(
        np.ascontiguousarray(c), np.ascontiguousarray(first, dtype=np.int64),
        np.ascontiguousarray(weights),
        np.ascontiguousarray(rates) if rates is not None else np.zeros((0, 4)),
        np.ascontiguousarray(radar.map_a), np.ascontiguousarray(radar.map_c),
        np.ascontiguousarray(radar.measured), m, np.ascontiguousarray(full[:4], dtype=float),
        1.0 / radar.site.measurement_sigmas()[:m], rows, kinds)
    if zenith:
        raise ValueError("azimuth Jacobian is undefined at the zenith (zero ground range)")
    return e, hx, hb, position, velocity if rates is not None else None


#: The free terms :func:`plots_on_paths_compiled` forms: the kind of their column in
#: :func:`graphcal.model.path_loops.plot_linearisation` and their row.
_COMPILED_TERM_KINDS: dict[str, tuple[int, int]] = {
    "range_offset": (path_kernels.TERM_ADDITIVE, 0),
    "range_gain": (path_kernels.TERM_RANGE_GAIN, 0),
    "azimuth_bias": (path_kernels.TERM_ADDITIVE, 1),
    "elevation_bias": (path_kernels.TERM_ADDITIVE, 2),
    "time_offset": (path_kernels.TERM_TIME_OFFSET, 0),
}


def _basis_rate(u: FloatArray, spacing_s: float) -> FloatArray:
    """``d B_j / dt`` ``(n, 4)`` [1/s]."""
    return basis_derivative(u) / spacing_s


# --------------------------------------------------------------------------- building
def build_trajectory_block(
    dataset: Dataset,
    terms: dict[str, RadarTerms],
    keys: dict[str, int],
    variable_radars: list[str],
    kernel: RobustKernel,
    *,
    use_adsb: bool,
    initial_biases: dict[str, FloatArray],
    height_key: int | None = None,
    spacing_s: float = KNOT_SPACING_S,
    progress: Progress | None = None,
    plots: Mapping[str, PlotArrays] | None = None,
    tracks: AdsbTrackTable | None = None,
) -> TrajectoryBlock | None:
    """The paths of every aircraft that links two radars or a radar and ADS-B, fitted at
    the initial biases, their process noise estimated; ``None`` when there is none.

    ``initial_biases``: each radar's free values to start from.  ``variable_radars``:
    the radars whose free terms are variables (others enter with their fixed terms).
    ``plots`` and ``tracks``: every radar's plots as arrays and the ADS-B tracks, when the
    caller keeps them (:class:`graphcal.model.problem.Problem`).
    """
    if plots is None:
        plots = {rid: plot_arrays(dataset, rid) for rid in dataset.radar_ids}
    sites = dataset.sites
    frame = NetworkFrame.of(list(sites.values()))
    names = sorted(dataset.radar_ids)  # the radars' order does not matter
    rows_of, radar_of, target_of, time_of = [], [], [], []
    for r, rid in enumerate(names):
        mine = plots[rid]
        usable = np.isfinite(mine.range_m) & np.isfinite(mine.azimuth_rad)
        if sites[rid].is_3d:
            usable &= np.isfinite(mine.elevation_rad)
        k = np.flatnonzero(usable)
        rows_of.append(k)
        radar_of.append(np.full(len(k), r))
        target_of.append(np.asarray(mine.target_id, dtype=object)[k])
        time_of.append(mine.time_s[k])
    code, path_target_names = _target_codes(np.concatenate(target_of))
    named = code >= 0
    k_all = np.concatenate(rows_of)[named]
    radar_all = np.concatenate(radar_of)[named]
    code = code[named]
    time_arr = np.concatenate(time_of)[named]
    if len(code) == 0:
        return None
    # By aircraft (its name's order), then time; ties in the radars' name order.
    order = np.lexsort((time_arr, code))
    k_all, radar_all, code, time_arr = k_all[order], radar_all[order], code[order], time_arr[order]
    new_path = np.ones(len(code), dtype=bool)
    new_path[1:] = (code[1:] != code[:-1]) | (np.diff(time_arr) > PATH_SPLIT_GAP_S)
    path_id = np.cumsum(new_path) - 1
    first_row = np.flatnonzero(new_path)
    last_row = np.append(first_row[1:], len(code)) - 1
    pairs = np.unique(path_id * len(names) + radar_all)
    n_radars = np.bincount(pairs // len(names), minlength=len(first_row))
    start, end = time_arr[first_row].copy(), time_arr[last_row].copy()
    path_target = path_target_names[code[first_row]]
    # ADS-B on the paths.
    adsb_path = np.zeros(0, dtype=np.int64)
    adsb_rows = np.zeros(0, dtype=np.int64)
    if use_adsb and dataset.adsb is not None and len(dataset.adsb):
        tracks = adsb_track_table(dataset.adsb) if tracks is None else tracks
        code_of_path = tracks.codes(path_target.astype(object))
        rows, paths = [], []
        for p in np.flatnonzero(code_of_path >= 0):
            k = code_of_path[p]
            lo, hi = tracks.start[k], tracks.start[k + 1]
            t = tracks.time_s[lo:hi]
            inside = np.flatnonzero((t >= start[p] - ADSB_MARGIN_S) & (t <= end[p] + ADSB_MARGIN_S))
            rows.append(lo + inside)
            paths.append(np.full(len(inside), p))
        if rows:
            adsb_rows = np.concatenate(rows).astype(np.int64)
            adsb_path = np.concatenate(paths).astype(np.int64)
    n_adsb_of_path = np.bincount(adsb_path, minlength=len(start))
    keep = (n_radars >= 2) | ((n_radars >= 1) & (n_adsb_of_path >= 2))
    if not np.any(keep):
        return None
    renumber = np.full(len(keep), -1)
    renumber[keep] = np.arange(int(keep.sum()))
    in_table = keep[path_id]
    k_all, radar_all, path_id = k_all[in_table], radar_all[in_table], renumber[path_id[in_table]]
    in_kept = keep[adsb_path]
    adsb_rows, adsb_path = adsb_rows[in_kept], renumber[adsb_path[in_kept]]
    start, end, path_target = start[keep], end[keep], path_target[keep]
    if len(adsb_path):
        adsb_t = tracks.time_s[adsb_rows]
        np.minimum.at(start, adsb_path, adsb_t)
        np.maximum.at(end, adsb_path, adsb_t)
    layout = PathLayout.build(start - 1.0, end + 1.0, spacing_s, PHASE_S, VERTICAL_PHASE_S)
    # Radars on paths.
    radars: list[RadarOnPaths] = []
    for r, rid in enumerate(names):
        mine_rows = radar_all == r
        if not np.any(mine_rows):
            continue
        site = sites[rid]
        mine = plots[rid]
        # In an order set by the values (path, time, range, azimuth), not by the rows:
        # the same plots in another file order give the same sums, bit for bit.
        # The rows are already in (path, time) order (sorted by aircraft and time
        # above): only plots of one path at the same time need sorting further.
        k = k_all[mine_rows]
        path_of = path_id[mine_rows]
        t = mine.time_s[k]
        if np.any((np.diff(path_of) == 0) & (np.diff(t) == 0.0)):
            order = np.lexsort((mine.azimuth_rad[k], mine.range_m[k], t, path_of))
            k, path_of = k[order], path_of[order]
        a, c = frame.radar_map(site)
        measured = np.stack([mine.range_m[k], mine.azimuth_rad[k],
                             mine.elevation_rad[k] if site.is_3d else np.full(len(k), np.nan)],
                            axis=-1)
        altitude = np.full(len(k), np.nan)
        if not site.is_3d:
            altitude = mine.altitude_m[k].astype(float)
        radars.append(RadarOnPaths(rid, site, terms[rid], mine.index[k],
                                   path_of.astype(np.int64), mine.time_s[k], measured,
                                   altitude, a, c))
    # Variables: the variable radars seen, in the dataset's order (GTSAM keys), then the
    # height model when 2-D plots carry pressure altitudes.
    seen = {r.radar_id for r in radars}
    variables = [(keys[rid], rid, len(terms[rid].free)) for rid in dataset.radar_ids
                 if rid in seen and rid in variable_radars and terms[rid].free]
    pressure = bool(dataset.pressure_altitudes and height_key is not None and any(
        not r.site.is_3d and np.isfinite(r.altitude_m).any() for r in radars))
    if pressure:
        variables.append((int(height_key), "", 2))
    fixed_values = {rid: np.zeros(0) for rid in seen if rid not in
                    {name for _, name, _ in variables}}
    adsb = None
    if len(adsb_rows):
        adsb = _adsb_on_paths(layout, frame, tracks, adsb_rows, adsb_path)
    block = TrajectoryBlock(
        frame, layout, radars, adsb, kernel, variables, height_key if pressure else None,
        pressure, np.zeros((layout.n_coefficients, 3)),
        np.full(layout.n_phases, 1.0 / INITIAL_PROCESS_NOISE_M2_S3),
        np.full(layout.n_vertical_phases, 1.0 / INITIAL_PROCESS_NOISE_M2_S3),
        n_aircraft=len(pd.unique(path_target)), target_of_path=path_target,
        fixed_values=fixed_values,
    )
    start_values = [np.asarray(initial_biases.get(name, np.zeros(size)), dtype=float)
                    if name else np.zeros(2) for _, name, size in variables]
    if progress is not None:
        progress("aircraft paths", 0, 1)
    plot_system = initial_plot_system(block, block._split(start_values))
    block.coefficients = _initial_coefficients(block, plot_system)
    if block.adsb is not None:
        before = block.n_adsb_gated
        _gate_adsb(block, block._split(start_values))
        if block.n_adsb_gated != before:  # the first fit again, without those reports
            block.coefficients = _initial_coefficients(block, plot_system)
    if progress is not None:
        progress("aircraft paths", 1, 1)
    return block


def _target_codes(targets: NDArray[np.object_]) -> tuple[IntArray, NDArray[np.object_]]:
    """Each plot's aircraft as a code into the sorted aircraft names (text), -1 where the
    plot names none (missing or blank ``target_id``)."""
    raw, uniques = pd.factorize(targets, use_na_sentinel=True)
    text = np.asarray([str(u) for u in uniques], dtype=object)
    named = np.asarray([bool(t.strip()) for t in text], dtype=bool)
    names, code_of_text = np.unique(text[named], return_inverse=True)
    code_of_unique = np.full(len(uniques) + 1, -1, dtype=np.int64)  # [-1]: no name
    code_of_unique[np.flatnonzero(named)] = code_of_text
    return code_of_unique[raw], names.astype(object)


def _adsb_on_paths(layout: PathLayout, frame: NetworkFrame, tracks, rows: IntArray,
                   path: IntArray) -> AdsbOnPaths:
    ecef = take_rows(tracks.ecef_m, rows)
    sigma = tracks.sigma_m[rows]
    # Horizontal sigma, 1.5 x vertically, about the report's own vertical: the
    # ellipsoid's normal, the gradient of x^2/a^2 + y^2/a^2 + z^2/b^2 (at a few km above
    # the ellipsoid within 1e-6 rad of the normal through the point).
    b2 = frames.WGS84_A_M**2 * (1.0 - frames.WGS84_E2)
    axes2 = np.array([frames.WGS84_A_M**2, frames.WGS84_A_M**2, b2])
    if path_kernels.enabled():
        position, information = path_kernels.compiled().adsb_reports(
            np.ascontiguousarray(ecef, dtype=float), np.ascontiguousarray(sigma, dtype=float),
            frame.origin_ecef_m, np.ascontiguousarray(frame.rotation),
            float(ADSB_VERTICAL_SIGMA_RATIO), axes2)
    else:
        position = frame.from_ecef(ecef)
        normal = ecef / axes2
        up = frames.rotate(normal / frames.row_norm(normal)[:, None], frame.rotation)
        horizontal = 1.0 / sigma**2
        vertical = 1.0 / (ADSB_VERTICAL_SIGMA_RATIO * sigma) ** 2
        information = (horizontal[:, None, None] * np.eye(3)[None]
                       + (vertical - horizontal)[:, None, None] * up[:, :, None]
                       * up[:, None, :])
    time_s = tracks.time_s[rows]
    return _adsb_constants(layout, path, time_s, position, information)


def _adsb_constants(layout: PathLayout, path: IntArray, time_s: FloatArray,
                    position: FloatArray, information: FloatArray) -> AdsbOnPaths:
    first, u = layout.locate(path, time_s)
    weights = basis(u)
    interval_offset = np.concatenate([[0], np.cumsum(layout.n_intervals)[:-1]])
    interval = interval_offset[path] + (first - layout.first_coefficient[path])
    band, rhs, constant = _adsb_sums(layout, first, weights, position, information)
    return AdsbOnPaths(path, time_s, position, information, first, weights, interval, band, rhs,
                       constant)


def _adsb_sums(layout: PathLayout, first: IntArray, weights: FloatArray, position: FloatArray,
               information: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """The reports' share of the paths' normal matrix, right-hand side and constant."""
    band = band_zeros(layout.n_unknowns)
    if path_kernels.enabled():
        rhs = np.zeros(layout.n_unknowns)
        constant = path_kernels.compiled().adsb_sums(
            band, rhs, np.ascontiguousarray(first, dtype=np.int64), np.ascontiguousarray(weights),
            np.ascontiguousarray(position), np.ascontiguousarray(information))
        return band, rhs, float(constant)
    add_measurement_blocks(band, first, weights, information)
    rhs = scatter_vectors(first, weights, np.einsum("nij,nj->ni", information, position),
                          layout.n_unknowns)
    constant = 0.5 * float(np.einsum("ni,nij,nj->", position, information, position))
    return band, rhs, constant


def _reweighted(layout: PathLayout, a: AdsbOnPaths, weight: FloatArray) -> AdsbOnPaths:
    """``a`` with each report's information multiplied by ``weight`` (0 leaves it out).

    Only the reports whose weight is not 1 are summed again, and their change added to
    the constants: the gate touches a handful of reports among tens of thousands.
    """
    changed = np.flatnonzero(weight != 1.0)
    if len(changed) == 0:
        return a
    delta = (weight[changed] - 1.0)[:, None, None] * a.information[changed]
    band, rhs, constant = _adsb_sums(layout, a.first[changed],
                                     a.weights[changed], a.position[changed], delta)
    keep = weight > 0.0
    information = take_rows(a.information, keep)
    if np.any(weight[changed] > 0.0):  # else (the gate's 0 or 1) the kept are as they were
        information *= weight[keep, None, None]
    return AdsbOnPaths(a.path[keep], a.time_s[keep], take_rows(a.position, keep), information,
                       a.first[keep], take_rows(a.weights, keep), a.interval[keep],
                       a.band + band, a.rhs + rhs,
                       a.constant + constant)


def _gate_adsb(block: TrajectoryBlock, named: dict[str, FloatArray]) -> None:
    """Leave out the ADS-B reports beyond :data:`ADSB_GATE_SIGMA` of a robust first fit.

    The first fit is refitted :data:`ADSB_GATE_ITERATIONS` times with each report's
    weight ``min(1, gate / s)`` (Huber's, ``s`` its whitened residual), so that a
    report kilometres off does not drag the path, and its neighbours with it, beyond
    the gate; then the reports beyond the gate are left out.
    """
    a = block.adsb
    assert a is not None

    def whitened_residual() -> FloatArray:
        return np.sqrt(weighted_squares(block.coefficients, a.first, a.weights, a.position,
                                        a.information))

    s = whitened_residual()
    for _ in range(ADSB_GATE_ITERATIONS):
        if s.max(initial=0.0) <= ADSB_GROSS_SIGMA:
            break  # nothing gross enough to drag the first fit: gate as it is
        weight = np.minimum(1.0, ADSB_GATE_SIGMA / np.maximum(s, 1e-300))
        block.adsb = _reweighted(block.layout, a, weight)
        block._settle_paths(named, 1)
        s = whitened_residual()
    good = s <= ADSB_GATE_SIGMA
    block.n_adsb_gated = int(np.sum(~good))
    block.adsb = _reweighted(block.layout, a, good.astype(float))


def _initial_coefficients(block: TrajectoryBlock, plot_system: tuple[FloatArray, FloatArray]
                          ) -> FloatArray:
    """Paths fitted to the ADS-B reports (those :attr:`TrajectoryBlock.adsb` holds now)
    and the plots converted at the initial biases (``plot_system``,
    :func:`initial_plot_system`).  Only a start for the Gauss-Newton steps of the paths.
    """
    band, rhs = plot_system
    band, rhs = band.copy(order="F"), rhs.copy()
    if block.adsb is not None:
        band += block.adsb.band
        rhs += block.adsb.rhs
    band[0] += RIDGE * np.maximum(band[0].max(initial=1.0), 1.0) + 1e-12
    factor = BandFactor.of(band, overwrite=True)
    return factor.solve(rhs).reshape(-1, 3)


def initial_plot_system(block: TrajectoryBlock, named: dict[str, FloatArray]
                         ) -> tuple[FloatArray, FloatArray]:
    """The normal matrix (band) and right-hand side of the first fit's plots and prior.

    A linear least-squares spline fit with isotropic weights per plot (its larger
    polar sigma at its range); 2-D plots at their reported heights, those without one
    left out; the motion prior of :data:`INITIAL_PROCESS_NOISE_M2_S3`.  Kept apart from
    the ADS-B reports', so that the fit is made again without the reports the gate
    leaves out (:func:`_gate_adsb`) without summing the plots again.
    """
    layout = block.layout
    n = layout.n_unknowns
    band = band_zeros(n)
    add_motion_prior(band, layout, np.full(layout.n_phases, 1.0 / INITIAL_PROCESS_NOISE_M2_S3))
    rhs = np.zeros(n)
    for radar in block.radars:
        terms = radar.terms
        full = terms.full_terms(named.get(radar.radar_id, np.zeros(0)))
        bias = terms.bias(named.get(radar.radar_id, np.zeros(0)))
        r, az, el = correct_bias(radar.measured[:, 0], radar.measured[:, 1],
                                 radar.measured[:, 2], bias)
        site = radar.site
        if not site.is_3d:
            height = radar.altitude_m
            if block.pressure and "" in named:
                d, k = named[""]
                height = (1.0 + k) * height + d
            el = frames.elevation_from_height(r, height, site.lat_rad, site.alt_m)
            ok = np.isfinite(el) & (el < MAX_2D_ELEVATION_RAD)
        else:
            ok = np.isfinite(el)
        ok &= np.isfinite(r) & (r > 0.0)  # a range no correction makes positive: left out
        r = np.where(ok, r, 1.0)
        el = np.where(ok, el, 0.0)
        sigma = np.maximum(site.sigma_range_m, r * site.sigma_azimuth_rad)
        weight = np.where(ok, 1.0 / sigma**2, 0.0)
        first, u = layout.locate(radar.path, radar.time_s - full[4])
        weights = basis(u)
        if path_kernels.enabled():  # the same sums in one compiled pass
            plots_rhs = np.zeros(n)
            path_kernels.compiled().add_plot_positions(
                band, plots_rhs, np.ascontiguousarray(first, dtype=np.int64), weights,
                np.ascontiguousarray(r), np.ascontiguousarray(az, dtype=float),
                np.ascontiguousarray(el, dtype=float), weight,
                np.ascontiguousarray(radar.map_a), np.ascontiguousarray(radar.map_c))
            rhs += plots_rhs
            continue
        enu = frames.polar_to_enu(r, az, el)
        local = frames.rotate(enu - radar.map_c, radar.map_a.T)  # radar ENU = A p + c
        info = weight[:, None, None] * np.eye(3)[None]
        kept_weights = take_rows(weights, ok)
        add_measurement_blocks(band, first[ok], kept_weights, take_rows(info, ok))
        rhs += scatter_vectors(first[ok], kept_weights, weight[ok, None] * take_rows(local, ok),
                               n)
    return band, rhs


__all__ = ["HALF_BANDWIDTH", "KNOT_SPACING_S", "NetworkFrame", "PROCESS_NOISE_GRID_M2_S3",
           "TERM_NAMES", "TrajectoryBlock", "build_trajectory_block", "compiled_plot_model",
           "initial_plot_system", "plots_on_paths", "plots_on_paths_compiled"]
