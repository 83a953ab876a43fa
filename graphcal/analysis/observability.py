"""What a dataset's traffic tells about each bias: information matrix, Deg, excitation.

Paper 001 measures how well the data determine the biases by the
observability degree ``Deg = lambda_min / lambda_max`` of the (Jacobi-scaled)
information matrix ``A = sum_k H_k^T W_k H_k`` (eq. 11).  This module builds
``A`` from a dataset's observations, as one of two estimators sees them:

* ``"graph"``: the graph calibrator's factors (:mod:`graphcal.solvers.graph`):
  ADS-B-matched plots in the radar's measurement space, and the pairwise
  cross-radar differences of the plots not matched to ADS-B;
* ``"wls"``: paper 001's cross-radar observations only
  (:func:`graphcal.model.cross_radar.cross_observations`).

Jacobians are taken at zero bias (the biases move the geometry negligibly).
From ``A``: the rank, the condition number and Deg; the weakest directions in
parameter terms; per parameter its *excitation* - the sigma it would have if
every other bias were known, ``1 / sqrt(A_ii)``, against its joint sigma
``sqrt((A^-1)_ii)`` - whose squared ratio is the variance inflation factor (VIF):
a VIF of 10 means the other biases take 90 % of what the traffic says about
this one.  :func:`degree_curve` follows Deg as the observations arrive in time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.data.align import DEFAULT_ADSB_MAX_GAP_S
from graphcal.data.bias import CONTRACT_KEYS
from graphcal.data.dataset import Dataset
from graphcal.model.information import PseudoInverse, jacobi_scale, pseudo_inverse

FloatArray = NDArray[np.float64]
Label = tuple[str, str]

#: Observability methods.
OBSERVABILITY_METHODS: tuple[str, ...] = ("graph", "wls")
#: A parameter whose variance inflation factor exceeds this is reported as confounded.
VIF_WARNING = 10.0


@dataclass
class ObservationBlock:
    """One group of observations (one radar's ADS-B-matched plots, or one radar pair).

    Attributes
    ----------
    time_s : ndarray (n,)
        Observation times [s].
    columns : list of int
        The global parameter columns its Jacobian covers.
    jacobian : ndarray (n, m, k)
        Whitened Jacobian of each observation (``m`` rows, ``k = len(columns)``).
    kind : str
        ``"adsb"`` or ``"pair"``.
    plot_rows : ndarray (n, j) of int
        Row labels in ``dataset.plots`` of the plots behind each observation
        (the plot itself for ADS-B; radar b's plot and radar a's two bracketing
        plots for a pair).
    target_id : ndarray (n,) of str
        The aircraft observed.
    """

    time_s: FloatArray
    columns: list[int]
    jacobian: FloatArray
    kind: str
    plot_rows: NDArray[np.int64]
    target_id: NDArray[np.object_]

    def __len__(self) -> int:
        return len(self.time_s)


@dataclass
class ObservationBlocks:
    """Whitened observation Jacobians of a dataset, grouped as they were built.

    Attributes
    ----------
    labels : list of (radar_id, parameter name)
        The parameters (global columns).
    blocks : list of ObservationBlock
    """

    labels: list[Label]
    blocks: list[ObservationBlock] = field(default_factory=list)

    def __len__(self) -> int:
        return int(sum(len(b) for b in self.blocks))

    def information(self, until_s: float | None = None) -> FloatArray:
        """``A = sum_k J_k^T J_k`` over the observations (up to ``until_s`` if given)."""
        p = len(self.labels)
        a = np.zeros((p, p))
        for block in self.blocks:
            rows = slice(None) if until_s is None else block.time_s <= until_s
            j = block.jacobian[rows]
            a[np.ix_(block.columns, block.columns)] += np.einsum("nip,niq->pq", j, j)
        return a


def observation_blocks(
    dataset: Dataset,
    method: str = "graph",
    *,
    use_adsb: bool = True,
    max_gap_s: float = DEFAULT_ADSB_MAX_GAP_S,
    linearise: str = "plots",
) -> ObservationBlocks:
    """The whitened observation Jacobians of ``dataset`` as ``method`` sees them.

    Parameters
    ----------
    dataset : Dataset
        Sites with their random-error sigmas (estimate missing ones first).
    method : {"graph", "wls"}
        Whose observations (module docstring).
    use_adsb : bool
        ``graph``: use the ADS-B table when there is one.
    max_gap_s : float
        Longest ADS-B gap bridged by interpolation [s].
    linearise : {"plots", "neighbours"}
        Where the cross-radar Jacobians are evaluated: at the plots, or at each
        plot's track neighbours (:func:`graphcal.data.align.neighbour_plots`), whose
        noise is independent of the observation's.  A selection made on the
        latter does not prefer observations for their own noise (which would
        bias the estimate on the selection).

    Returns
    -------
    ObservationBlocks
    """
    if linearise not in ("plots", "neighbours"):
        raise ValueError(f"linearise must be 'plots' or 'neighbours', not '{linearise}'")
    if method not in OBSERVABILITY_METHODS:
        raise ValueError(
            f"unknown observability method '{method}'; use one of: "
            f"{', '.join(OBSERVABILITY_METHODS)}"
        )
    for site in dataset.sites.values():
        sig = site.measurement_sigmas()[: 3 if site.is_3d else 2]
        if not np.all(np.isfinite(sig) & (sig > 0)):
            raise ValueError(
                f"radar {site.id}: its random-error sigmas are missing from sites.toml; "
                "estimate them first (graphcal noise DIR --write-sites ...)"
            )
    if method == "wls":
        return _wls_blocks(dataset, linearise)
    return _graph_blocks(dataset, use_adsb, max_gap_s, linearise)


def excluded_parameters_note(dataset: Dataset, method: str = "graph", *,
                             use_adsb: bool = True) -> str | None:
    """What the observability analysis leaves out that a calibration may estimate.

    The analysis covers the biases of the measurement model (range offset and gain,
    azimuth, elevation, eccentricity): not the radars' time-stamping biases
    (``time_offset_s``), which ``graphcal calibrate`` estimates, with ADS-B, for the
    radars whose traffic determines them.  So the two count different parameters on
    the same data (16 against 21 on the demo network); this says so, in one line.
    """
    radars = len(dataset.radar_ids)
    if not radars:
        return None
    have_adsb = bool(use_adsb and dataset.adsb is not None and len(dataset.adsb) > 0)
    if method == "graph" and have_adsb:
        return (f"time offsets (time_offset_s) are not included: calibrate also estimates "
                f"them with ADS-B, up to {radars} more parameters (one per radar whose "
                "traffic determines it)")
    return ("time offsets (time_offset_s) are not included; they need ADS-B, so "
            "calibrate does not estimate them here either")


def _graph_blocks(
    dataset: Dataset, use_adsb: bool, max_gap_s: float, linearise: str
) -> ObservationBlocks:
    import dataclasses

    from graphcal.data.align import neighbour_plots
    from graphcal.model.factor_set import FactorSet, build_factors
    from graphcal.model.parameters import radar_terms
    from graphcal.model.robust import RobustKernel
    from graphcal.solvers.gtsam_adapter import symbol

    radar_ids = list(dataset.radar_ids)
    terms = {rid: radar_terms(dataset.sites[rid], {}) for rid in radar_ids}
    keys = {rid: symbol("b", i) for i, rid in enumerate(radar_ids)}
    factor_set = FactorSet(terms, keys)
    have_adsb = bool(use_adsb and dataset.adsb is not None and len(dataset.adsb) > 0)
    build_factors(dataset, factor_set, have_adsb, "pairwise", RobustKernel("none"), max_gap_s,
                   None, None)
    labels = [(rid, name) for rid in radar_ids for name in terms[rid].free]
    column = {label: i for i, label in enumerate(labels)}
    out = ObservationBlocks(labels)
    plot_time = dataset.plots["time_s"]
    plot_target = dataset.plots["target_id"].astype(str)
    for rid, f in factor_set.adsb.items():
        zero = np.zeros(len(terms[rid].free))
        _, (jac,) = f.whitened([zero])
        cols = [column[(rid, name)] for name in terms[rid].free]
        rows = np.asarray(f.plot_rows, dtype=np.int64)
        out.blocks.append(ObservationBlock(
            plot_time.loc[rows].to_numpy(float), cols, jac, "adsb", rows[:, None],
            plot_target.loc[rows].to_numpy(object),
        ))
    for f in factor_set.pairs:
        ra, rb = f.terms_a.radar_id, f.terms_b.radar_id
        zeros = [np.zeros(len(terms[ra].free)), np.zeros(len(terms[rb].free))]
        at = f if linearise == "plots" else dataclasses.replace(
            f, a_plots=neighbour_plots(f.a_plots), b_plots=neighbour_plots(f.b_plots))
        _, (ja, jb) = at.whitened(zeros)
        cols = ([column[(ra, n)] for n in terms[ra].free]
                + [column[(rb, n)] for n in terms[rb].free])
        rows = np.stack([f.b_plots.index[f.ib], f.a_plots.index[f.i0],
                         f.a_plots.index[f.i0 + 1]], axis=1).astype(np.int64)
        out.blocks.append(ObservationBlock(
            f.b_plots.time_s[f.ib], cols, np.concatenate([ja, jb], axis=2), "pair", rows,
            f.b_plots.target_id[f.ib].astype(str).astype(object),
        ))
    return out


def _wls_blocks(dataset: Dataset, linearise: str) -> ObservationBlocks:
    from graphcal.model.cross_radar import cross_observations
    from graphcal.model.parameters import ParameterLayout
    from graphcal.solvers.wls import whiten

    layout = ParameterLayout.for_sites(list(dataset.sites.values()))
    obs = cross_observations(dataset, layout, linearise=linearise)
    out = ObservationBlocks(list(layout.labels))
    if len(obs):
        h_white, _ = whiten(obs)
        target = dataset.plots["target_id"].astype(str).loc[obs.plot_rows[:, 0]]
        out.blocks.append(ObservationBlock(
            obs.time_s, list(range(len(layout))), h_white, "pair",
            obs.plot_rows.astype(np.int64), target.to_numpy(object),
        ))
    return out


# --------------------------------------------------------------------------- figures
@dataclass
class ObservabilityReport:
    """Observability figures of one dataset (see the module docstring).

    Attributes
    ----------
    labels : list of (radar_id, parameter name)
    information : ndarray (p, p)
        ``A`` in SI units (m, fraction, rad).
    rank : int
    condition : float
        Condition number of the Jacobi-scaled ``A`` (inf when singular).
    degree : float
        ``Deg = 1 / condition`` (paper 001 eq. 11).
    eigenvalues : ndarray (p,)
        Of the scaled ``A``, ascending.
    directions : ndarray (p, p)
        The matching unit eigenvectors (columns), in scaled parameters.
    sigma_alone : ndarray (p,)
        ``1 / sqrt(A_ii)`` [SI]: the parameter's sigma were every other bias known.
    sigma_joint : ndarray (p,)
        ``sqrt((A^+)_ii)`` [SI]: its sigma with all of them estimated (inf if not
        determined).
    n_observations : int
    """

    labels: list[Label]
    information: FloatArray
    rank: int
    condition: float
    degree: float
    eigenvalues: FloatArray
    directions: FloatArray
    sigma_alone: FloatArray
    sigma_joint: FloatArray
    n_observations: int

    @property
    def inflation(self) -> FloatArray:
        """Variance inflation factor ``(sigma_joint / sigma_alone)^2`` per parameter."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return (self.sigma_joint / self.sigma_alone) ** 2

    def weak_directions(self, threshold: float = 1e-4, limit: int = 3) -> list[str]:
        """Plain-language sentences for the directions the traffic hardly determines.

        Every direction whose scaled eigenvalue is below ``threshold`` times the
        largest (at most ``limit``, weakest first) names the parameters that
        make up most of it.
        """
        top = self.eigenvalues[-1] if len(self.eigenvalues) else 0.0
        out = []
        for i in range(min(limit, len(self.eigenvalues))):
            if top <= 0 or self.eigenvalues[i] >= threshold * top:
                break
            v = self.directions[:, i]
            involved = [self._name(j) for j in np.argsort(-np.abs(v)) if abs(v[j]) > 0.3]
            ratio = max(self.eigenvalues[i], 0.0) / top
            if len(involved) == 1:
                out.append(f"{involved[0]} is not determined by this traffic "
                           f"(relative eigenvalue {ratio:.2g})")
            else:
                out.append(f"{' and '.join([', '.join(involved[:-1]), involved[-1]])} "
                           f"cannot be told apart with this traffic "
                           f"(relative eigenvalue {ratio:.2g})")
        return out

    def confounded(self, threshold: float = VIF_WARNING) -> list[str]:
        """Parameters whose variance inflation exceeds ``threshold``, with their main partner."""
        out = []
        covariance = _pinv(self.information)
        d = np.sqrt(np.clip(np.diag(covariance), 1e-300, None))
        correlation = covariance / np.outer(d, d)
        for i, vif in enumerate(self.inflation):
            if not np.isfinite(vif) or vif <= threshold:
                continue
            rho = correlation[i].copy()
            rho[i] = 0.0
            j = int(np.argmax(np.abs(rho)))
            out.append(
                f"{self._name(i)} is poorly excited: estimating the other biases multiplies "
                f"its sigma by {np.sqrt(vif):.1f} (mostly {self._name(j)}, correlation "
                f"{rho[j]:+.2f})"
            )
        return out

    def _name(self, i: int) -> str:
        rid, name = self.labels[i]
        return f"{rid} {name.replace('_', ' ')}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready figures in contract units."""
        per = {}
        for i, (rid, name) in enumerate(self.labels):
            key, scale = CONTRACT_KEYS[name]
            per[f"{rid}.{key}"] = {
                "sigma_alone": _finite(self.sigma_alone[i] * scale),
                "sigma_joint": _finite(self.sigma_joint[i] * scale),
                "inflation": _finite(self.inflation[i]),
            }
        return {
            "rank": self.rank,
            "n_parameters": len(self.labels),
            "condition": _finite(self.condition),
            "degree": self.degree,
            "n_observations": self.n_observations,
            "parameters": per,
            "weak_directions": self.weak_directions(),
            "confounded": self.confounded(),
        }


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _pinv(information: FloatArray, inverse: PseudoInverse | None = None) -> FloatArray:
    """Pseudo-inverse through the Jacobi scaling; undetermined diagonal entries are inf."""
    if inverse is None:
        inverse = pseudo_inverse(information)
    covariance = inverse.covariance.copy()
    diag = np.diag(covariance).copy()
    diag[inverse.undetermined] = np.inf
    np.fill_diagonal(covariance, diag)
    return covariance


def analyse(blocks: ObservationBlocks) -> ObservabilityReport:
    """:class:`ObservabilityReport` of all the observations in ``blocks``."""
    return report_from_information(list(blocks.labels), blocks.information(), len(blocks))


def report_from_information(
    labels: list[Label], a: FloatArray, n_observations: int = 0
) -> ObservabilityReport:
    """:class:`ObservabilityReport` of an information matrix ``a`` [SI] over ``labels``."""
    p = len(labels)
    if p == 0:
        raise ValueError("no parameters: the dataset has no usable observation")
    s = jacobi_scale(a)
    scaled = a * np.outer(s, s)
    w, v = np.linalg.eigh(0.5 * (scaled + scaled.T))
    top = max(float(w[-1]), 0.0)
    inverse = pseudo_inverse(a)
    rank = inverse.rank
    # Rank-deficient: the smallest eigenvalue is round-off, so Deg is 0 and cond inf.
    low = max(float(w[0]), 0.0) if rank == p else 0.0
    condition = top / low if low > 0 else np.inf
    diag = np.diag(a)
    with np.errstate(divide="ignore"):
        alone = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), np.inf)
    joint = np.sqrt(np.diag(_pinv(a, inverse)))
    return ObservabilityReport(
        labels=list(labels), information=a, rank=rank, condition=condition,
        degree=low / top if top > 0 else 0.0, eigenvalues=w, directions=v,
        sigma_alone=alone, sigma_joint=joint, n_observations=n_observations,
    )


def degree_curve(
    blocks: ObservationBlocks, points: int = 60
) -> tuple[FloatArray, NDArray[np.int64], FloatArray]:
    """Deg as the observations arrive in time order.

    Returns ``(time_s, n_observations, degree)`` at ``points`` times evenly spread
    over the observations' time span (each point: all observations up to then).
    The information is accumulated per time bin, not recomputed from scratch.
    """
    times = (np.concatenate([b.time_s for b in blocks.blocks]) if blocks.blocks
             else np.zeros(0))
    if len(times) == 0:
        return np.zeros(0), np.zeros(0, np.int64), np.zeros(0)
    edges = np.linspace(times.min(), times.max(), points + 1)[1:]
    p = len(blocks.labels)
    increments = np.zeros((points, p, p))
    counts = np.zeros(points, dtype=np.int64)
    for block in blocks.blocks:
        cols = block.columns
        bin_of = np.minimum(np.searchsorted(edges, block.time_s, side="left"), points - 1)
        per_bin = np.zeros((points, len(cols), len(cols)))
        np.add.at(per_bin, bin_of, np.einsum("nip,niq->npq", block.jacobian, block.jacobian))
        idx = np.ix_(np.arange(points), cols, cols)
        increments[idx] += per_bin
        np.add.at(counts, bin_of, 1)
    a = np.cumsum(increments, axis=0)
    degree = np.zeros(points)
    for k in range(points):
        s = jacobi_scale(a[k])
        w = np.linalg.eigvalsh(a[k] * np.outer(s, s))
        degree[k] = max(float(w[0]), 0.0) / w[-1] if w[-1] > 0 else 0.0
    return edges, np.cumsum(counts), degree
