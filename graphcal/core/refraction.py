"""Atmospheric refraction of radar rays: an exponential atmosphere about the radar's earth sphere.

Contract version 2 (``refraction = "exponential"`` in ``sites.toml``).  The
refractive index depends on the height ``h`` only::

    n(h) = 1 + 1e-6 N_s exp(-h / H)

with ``N_s`` the surface refractivity [N-units] and ``H`` the scale height [m]
(:class:`Atmosphere`).  The atmosphere is spherically stratified about the
radar's *local earth sphere*: radius ``R``, the Gaussian radius of curvature of
WGS-84 at the radar's latitude (:func:`graphcal.core.frames.gaussian_radius_m`),
centre on the antenna's vertical, ``R + h_radar`` below the antenna, i.e. at
``(0, 0, -(R + h_radar))`` in the radar's ENU frame.  A point's height in the
stratification is its distance ``r`` from that centre minus ``R``.

A ray stays in the plane through the centre, the antenna and the target, so
its azimuth is the straight-line ENU azimuth.  In that plane, with ``e(r)`` the
ray's elevation above the local horizontal where it crosses radius ``r``, the
spherical Snell invariant holds along the ray::

    u(r) cos e(r) = c,        u(r) = n(r) r   (the "modified radius")

so that ``c = u0 cos e0`` with ``u0 = n(r0) r0`` the antenna's and ``e0`` the
apparent elevation.  With ``ds`` the arc length, ``dr = ds sin e`` and
``r dtheta = ds cos e``, the central angle swept and the electrical length
(what a radar's delay measures) are::

    theta = ∫ c dr / (r sqrt(u^2 - c^2)),      L = ∫ n ds = ∫ n^2 r dr / sqrt(u^2 - c^2)

Both integrands have an inverse-square-root singularity where the ray is
horizontal (``u = c``: at the antenna for ``e0 = 0``, at the lowest point of a
ray that dips and rises again).  The substitution::

    tau = sqrt(u^2 - c^2) = u sin e,     dtau = u u' dr / tau,   u' = du/dr = n + r dn/dr

removes it::

    theta = ∫ c / (r u u') dtau,              L = ∫ n / u' dtau

with ``u = sqrt(tau^2 + c^2)`` and ``r`` the root of ``n(r) r = u`` (``u`` is
increasing in ``r`` unless the atmosphere ducts, which :class:`Atmosphere`
excludes).  Taking ``tau`` signed (negative while the ray descends), a ray
from the antenna (``tau0 = u0 sin e0``) to any point on it (``tau_t``) is one
integral over ``[tau0, tau_t]`` whose integrand is analytic in ``tau``, even
through the ray's lowest point (``tau = 0``): rays going up, going down, and
rays that dip and rise again are the same formula, integrated with a fixed
Gauss-Legendre rule (:data:`QUADRATURE_NODES` nodes; graded panels for rays
that climb far above most of the atmosphere, see :func:`_integrate`).

The apparent elevation of a target at central angle ``theta_t`` and radius
``r_t`` solves, for the unknowns ``(e0, tau_t)``::

    E1 = theta(e0, tau_t) - theta_t = 0,      E2 = tau_t^2 + c^2 - u_t^2 = 0

by Newton's method (``E2`` keeps the system regular where the ray arrives
horizontally, ``tau_t = 0``).  It starts from the straight line over the
"effective earth" of the path's mean refractivity gradient (the 4/3-earth
model), within about 2e-5 rad of the answer, and converges in two or three
steps.  Its Jacobian needs, besides the integrands at the end points, the
integrals of their derivatives in ``c`` at fixed ``tau`` (``u_c = c / u``)::

    d/dc [c / (r u u')] = g (1 - (c^2 / u) g (u + r u' + r u u'' / u')),   g = 1 / (r u u')
    d/dc [n / u']       = (c / u) (n_r u' - n u'') / u'^3

The derivatives of ``(L, e0)`` in the target position follow from the
eikonal property of the electrical length (its gradient at the target is
``n_t`` times the ray's unit tangent there: ``dL/dr_t = n_t sin e_t = tau_t / r_t``,
``dL/dtheta_t = n_t r_t cos e_t = c``) and from implicit differentiation of
``(E1, E2)`` for ``e0``.  The inverses solve the same equations with the
electrical length given instead of the central angle.

With no atmosphere (``None``, or ``N_s = 0``) every function reduces exactly to
the straight line of sight of :mod:`graphcal.core.frames`.  Units: metres and
radians; ``N_s`` in N-units (``1e-6``).  Every function is vectorised over the
points (first axis) and a point's result does not depend on the others; a
radar's ``lat_rad`` and ``alt_m`` are scalars.

Accuracy, against an independent numerical ray trace and a high-order rule
(``tests/core/test_refraction.py``): for targets up to 30 km high and 500 km
away, and any accepted atmosphere, better than 1e-6 m in range and 1e-10 rad
in elevation (1e-8 m and 1e-12 rad for ``N_s = 313``, ``H = 7 km``, aircraft
heights); at the zenith up to 300 km, 2e-8 m.  Cost: about 3-5 us per target
(``benchmarks/bench_refraction.py``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from graphcal.core import frames

Array = NDArray[np.float64]

#: One N-unit of refractivity: ``n = 1 + N_UNIT * N``.
N_UNIT = 1e-6
#: Default surface refractivity [N-units] (``refractivity_n_s`` in ``sites.toml``).
DEFAULT_N_S = 313.0
#: Default scale height of the refractivity [m] (``refractivity_scale_height_m``).
DEFAULT_SCALE_HEIGHT_M = 7000.0
#: Largest surface refractivity gradient ``N_s / H`` accepted [N-units per metre]:
#: 79 N-units/km, the conventional onset of super-refraction (ducting starts at
#: 157).  With the default ``H = 7 km`` any ``N_s`` up to 553 passes.  The
#: standard atmosphere's gradient is about 40 N-units/km.
MAX_GRADIENT_N_PER_M = 0.079
#: The solver's floor: rays that would dip to where ``d(n r)/dr`` falls to this
#: value (several kilometres below the ellipsoid: a target deep below the
#: horizon) are not solved (NaN).
MIN_MODIFIED_RADIUS_SLOPE = 0.25
#: Gauss-Legendre nodes of the integrals over ``tau``, for atmospheres up to
#: :data:`STRONG_GRADIENT_N_PER_M` ...
QUADRATURE_NODES = 12
#: ... and above it, where the modified radius's slope ``u'`` falls further
#: near the ground and the integrands vary faster.
QUADRATURE_NODES_STRONG = 20
#: Surface refractivity gradient ``N_s / H`` [N-units per metre] above which the
#: integrals take :data:`QUADRATURE_NODES_STRONG` nodes (50 N-units/km).
STRONG_GRADIENT_N_PER_M = 0.05
#: Rays whose heights span more than this many scale heights (targets far above
#: most of the atmosphere) are integrated on graded panels (:func:`_integrate`).
LONG_SPAN_SCALE_HEIGHTS = 2.0
#: Newton iterations at most (the solves converge in 2 or 3).
MAX_ITERATIONS = 20
#: Newton stops once its step in the apparent elevation is below this [rad]; the
#: convergence is quadratic, so the solution is then exact to rounding.
ELEVATION_TOLERANCE_RAD = 1e-8
#: Newton stops once its step in ``tau`` is below this [m] (with the elevation's).
TAU_TOLERANCE_M = 0.05
#: Newton steps of the root of ``n(r) r = u`` stop below this step [m].
_RADIUS_TOLERANCE_M = 1e-6
#: ... or after this many steps (from ``r = u``; 4 for ``N_s = 313``, ``H = 7 km``).
_RADIUS_MAX_STEPS = 12

#: Edges of the graded panels of one side of a long ray, as fractions of the side
#: from its lowest point: each panel is 4 times longer than the one before.
_PANEL_EDGES = (0.0, 1.0 / 64.0, 1.0 / 16.0, 1.0 / 4.0, 1.0)


@dataclass(frozen=True)
class _Rule:
    """Gauss-Legendre rules: on [-1, 1], and composite on the graded panels of [0, 1]."""

    nodes: Array
    weights: Array
    side_nodes: Array
    side_weights: Array


@functools.cache
def _rule(n_nodes: int) -> _Rule:
    nodes, weights = np.polynomial.legendre.leggauss(n_nodes)
    panels = list(zip(_PANEL_EDGES[:-1], _PANEL_EDGES[1:], strict=True))
    return _Rule(
        nodes=nodes,
        weights=weights,
        side_nodes=np.concatenate([a + (b - a) * 0.5 * (nodes + 1.0) for a, b in panels]),
        side_weights=np.concatenate([(b - a) * 0.5 * weights for a, b in panels]),
    )


# Gauss-Legendre nodes on [0, 1] along a straight path, their weights (the mean), and
# the weights of the mean weighted by 2 (1 - s) (see _path_means).
_PATH_NODES, _PATH_WEIGHTS = np.polynomial.legendre.leggauss(3)
_PATH_NODES = 0.5 * (_PATH_NODES + 1.0)
_PATH_WEIGHTS = 0.5 * _PATH_WEIGHTS
_PATH_BEND_WEIGHTS = _PATH_WEIGHTS * 2.0 * (1.0 - _PATH_NODES)


@dataclass(frozen=True)
class Atmosphere:
    """An exponential atmosphere: ``n(h) = 1 + 1e-6 N_s exp(-h / H)``.

    Attributes
    ----------
    n_s : float
        Surface refractivity ``N_s`` [N-units], the refractivity at height 0
        (the ellipsoid); 0 means no refraction.  Climatological values lie
        between about 300 and 400; the mid-latitude annual mean is about 315-320.
    scale_height_m : float
        Scale height ``H`` [m] of the refractivity, about 7000 m.

    Raises
    ------
    ValueError
        If ``n_s`` is negative or not finite, ``scale_height_m`` is not
        positive, or the surface gradient ``N_s / H`` exceeds
        :data:`MAX_GRADIENT_N_PER_M` (a ducting atmosphere is not modelled).
    """

    n_s: float = DEFAULT_N_S
    scale_height_m: float = DEFAULT_SCALE_HEIGHT_M

    def __post_init__(self) -> None:
        if not math.isfinite(self.n_s) or self.n_s < 0.0:
            raise ValueError(f"surface refractivity must be finite and >= 0, got {self.n_s}")
        if not math.isfinite(self.scale_height_m) or self.scale_height_m <= 0.0:
            raise ValueError(f"scale height must be positive, got {self.scale_height_m}")
        gradient = self.n_s / self.scale_height_m
        if gradient > MAX_GRADIENT_N_PER_M:
            raise ValueError(
                f"refractivity gradient N_s/H = {gradient * 1e3:.0f} N-units/km exceeds "
                f"{MAX_GRADIENT_N_PER_M * 1e3:.0f} N-units/km (a ducting atmosphere is not "
                "modelled)")

    @property
    def refracts(self) -> bool:
        """False when ``n_s == 0``: rays are straight lines."""
        return self.n_s > 0.0

    def refractivity(self, height_m: ArrayLike) -> Array:
        """Refractivity ``N(h) = N_s exp(-h / H)`` [N-units] at heights [m]."""
        return self.n_s * np.exp(-np.asarray(height_m, dtype=float) / self.scale_height_m)

    def refractive_index(self, height_m: ArrayLike) -> Array:
        """Refractive index ``n(h) = 1 + 1e-6 N(h)`` at heights [m] above the ellipsoid."""
        return 1.0 + N_UNIT * self.refractivity(height_m)


#: No refraction: straight lines of sight.
NO_REFRACTION = Atmosphere(n_s=0.0)


@dataclass(frozen=True)
class RefractedRay:
    """The refracted ray from a radar's antenna to targets (arrays of one value per target).

    Attributes
    ----------
    range_m : ndarray
        Electrical length ``L = ∫ n ds`` [m]: the contract's ``range_true``.
    azimuth_rad : ndarray
        Azimuth, clockwise from north in ``[0, 2 pi)`` [rad] (the straight line's).
    elevation_rad : ndarray
        Apparent elevation ``e0``: the ray's elevation at the antenna [rad], the
        contract's ``elevation_true``.
    arrival_elevation_rad : ndarray
        The ray's elevation above the target's local horizontal, at the target
        [rad] (negative: the ray arrives descending).
    central_angle_rad : ndarray
        Angle at the sphere's centre between the antenna and the target [rad].
    target_height_m : ndarray
        Target height in the stratification: distance from the sphere's centre
        minus ``R`` [m].
    lowest_height_m : ndarray
        Lowest height of the ray between the antenna and the target [m]; below 0
        the Earth (the sphere) blocks the ray.
    """

    range_m: Array
    azimuth_rad: Array
    elevation_rad: Array
    arrival_elevation_rad: Array
    central_angle_rad: Array
    target_height_m: Array
    lowest_height_m: Array


# --------------------------------------------------------------------------- the sphere


class _Sphere:
    """An atmosphere about one radar's local earth sphere: ``n``, ``u = n r`` and their inverses."""

    def __init__(self, atmosphere: Atmosphere, lat_rad: float, alt_m: float) -> None:
        self.radius_m = float(frames.gaussian_radius_m(lat_rad))
        self.alt_m = float(alt_m)
        self.k = N_UNIT * atmosphere.n_s
        self.inv_h = 1.0 / atmosphere.scale_height_m
        self.r0 = self.radius_m + self.alt_m
        self.nu0 = self.nu(self.alt_m)
        self.u0 = self.r0 * (1.0 + self.nu0)
        self.du0 = 1.0 + self.nu0 * (1.0 - self.r0 * self.inv_h)
        strong = atmosphere.n_s / atmosphere.scale_height_m > STRONG_GRADIENT_N_PER_M
        self.rule = _rule(QUADRATURE_NODES_STRONG if strong else QUADRATURE_NODES)
        # The floor: u'(r_f) = MIN_MODIFIED_RADIUS_SLOPE (solved with r = R in 1 - r/H).
        nu_f = (1.0 - MIN_MODIFIED_RADIUS_SLOPE) / (self.radius_m * self.inv_h - 1.0)
        self.floor_height_m = -math.log(nu_f / self.k) / self.inv_h
        r_f = self.radius_m + self.floor_height_m
        self.u_floor = r_f * (1.0 + nu_f)
        self.du_floor = self.du(r_f, nu_f)

    def nu(self, height_m):
        """``n - 1`` at heights [m]."""
        return self.k * np.exp(-height_m * self.inv_h)

    def radius(self, u: Array) -> tuple[Array, Array]:
        """The radius ``r`` with ``n(r) r = u`` and ``n(r) - 1`` there.

        Newton's method from ``r = u`` (``u`` is convex in ``r``, so the iterates
        decrease monotonically to the root).  Below the floor (``u < u_floor``)
        ``u`` is continued linearly, so that every ``u`` has one radius.
        """
        below = u < self.u_floor
        target = np.maximum(u, self.u_floor)
        r = target
        nu = self.nu(r - self.radius_m)
        # Each value stops on its own (so that a result does not depend on the others
        # in the array); steps after convergence would only add rounding noise.
        active = np.ones(u.shape, dtype=bool)
        for _ in range(_RADIUS_MAX_STEPS):
            step = np.where(active, (r * (1.0 + nu) - target) / self.du(r, nu), 0.0)
            r = r - step
            nu = nu * np.exp(step * self.inv_h)
            active &= np.abs(step) >= _RADIUS_TOLERANCE_M
            if not np.any(active):
                break
        if np.any(below):
            r = np.where(below, r + (u - self.u_floor) / self.du_floor, r)
        return r, nu

    def du(self, r: Array, nu: Array) -> Array:
        """``u' = du/dr = n + r dn/dr = 1 + (n - 1)(1 - r / H)``."""
        return 1.0 + nu * (1.0 - r * self.inv_h)


@dataclass
class _Integrals:
    """Integrals over ``[tau0, tau_t]`` and the integrands at ``tau_t``."""

    theta: Array  # central angle
    length: Array  # electrical length
    theta_c: Array | None  # d theta / d c at fixed end points
    length_c: Array | None  # d L / d c at fixed end points
    f_theta_t: Array  # c / (r u u') at tau_t
    f_length_t: Array  # n / u' at tau_t
    u_t: Array  # u at tau_t
    r_t: Array  # r at tau_t
    du_t: Array  # u' at tau_t


def _integrate(sph: _Sphere, tau0: Array, tau_t: Array, c: Array, derivatives: bool
               ) -> _Integrals:
    """Gauss-Legendre integrals of the rays from ``tau0`` to ``tau_t`` (Snell invariant ``c``).

    One rule of :data:`QUADRATURE_NODES` nodes over the whole interval, unless the
    ray spans more than :data:`LONG_SPAN_SCALE_HEIGHTS` scale heights in height:
    then ``n - 1`` decays by orders of magnitude along it, and each side of the
    ray's lowest point ``tau_low`` (``tau = 0`` if the ray dips, else an end) gets
    a composite rule on panels graded towards ``tau_low`` (:data:`_PANEL_EDGES`).
    """
    u_t = np.hypot(tau_t, c)
    dips = (tau0 < 0.0) & (tau_t > 0.0)
    u_low = np.where(dips, c, np.minimum(sph.u0, u_t))
    long = np.maximum(sph.u0, u_t) - u_low > LONG_SPAN_SCALE_HEIGHTS / sph.inv_h
    if not np.any(long):
        rule = sph.rule
        half = 0.5 * (tau_t - tau0)
        tau = np.empty((tau0.size, rule.nodes.size + 1))
        np.multiply(half[:, None], rule.nodes, out=tau[:, :-1])
        tau[:, :-1] += (0.5 * (tau_t + tau0))[:, None]
        tau[:, -1] = tau_t
        return _integrate_nodes(sph, tau, half[:, None] * rule.weights, c, derivatives)
    short = ~long
    parts = [_integrate(sph, tau0[short], tau_t[short], c[short], derivatives)]
    t0, tt, cl = tau0[long], tau_t[long], c[long]
    tau_low = np.clip(0.0, np.minimum(t0, tt), np.maximum(t0, tt))
    side_0, side_t = t0 - tau_low, tt - tau_low
    nodes, weights = sph.rule.side_nodes, sph.rule.side_weights
    tau = np.concatenate([tau_low[:, None] + side_0[:, None] * nodes,
                          tau_low[:, None] + side_t[:, None] * nodes, tt[:, None]], axis=1)
    weights = np.concatenate([-side_0[:, None] * weights, side_t[:, None] * weights], axis=1)
    parts.append(_integrate_nodes(sph, tau, weights, cl, derivatives))
    merged = {}
    for name in vars(parts[0]):
        if getattr(parts[0], name) is None:
            merged[name] = None
            continue
        value = np.empty(tau0.size)
        value[short] = getattr(parts[0], name)
        value[long] = getattr(parts[1], name)
        merged[name] = value
    return _Integrals(**merged)


def _integrate_nodes(sph: _Sphere, tau: Array, weights: Array, c: Array, derivatives: bool
                     ) -> _Integrals:
    """The integrals from the integrands at nodes ``tau`` ``(n, m + 1)`` (the last: the end
    point ``tau_t``) with quadrature ``weights`` ``(n, m)``."""
    cc = c[:, None]
    u = np.sqrt(tau * tau + cc * cc)
    r, nu = sph.radius(u)
    du = sph.du(r, nu)
    g = 1.0 / (r * u * du)
    f_theta = cc * g
    f_length = (1.0 + nu) / du

    def total(f: Array) -> Array:
        return np.einsum("ij,ij->i", f[:, :-1], weights)

    theta_c = length_c = None
    if derivatives:
        ddu = nu * (r * sph.inv_h - 2.0) * sph.inv_h  # u''
        f_theta_c = g * (1.0 - (cc * cc / u) * g * (u + r * du + r * u * ddu / du))
        f_length_c = (cc / u) * (-nu * sph.inv_h * du - (1.0 + nu) * ddu) / du**3
        theta_c, length_c = total(f_theta_c), total(f_length_c)
    return _Integrals(
        theta=total(f_theta),
        length=total(f_length),
        theta_c=theta_c,
        length_c=length_c,
        f_theta_t=f_theta[:, -1],
        f_length_t=f_length[:, -1],
        u_t=u[:, -1],
        r_t=r[:, -1],
        du_t=du[:, -1],
    )


def _end_gap(sph: _Sphere, e0: Array, c: Array, dr_t: Array, nu_t: Array) -> Array:
    """``u_t^2 - c^2`` for a target ``dr_t = r_t - r0`` above the antenna radius, accurately.

    ``(u_t - c)(u_t + c)`` with ``u_t - c = (u_t - u0) + 2 u0 sin^2(e0 / 2)`` and
    ``u_t - u0 = dr_t (1 + nu_t) + r0 (nu_t - nu0)``: no difference of large numbers.
    """
    u_t = (sph.r0 + dr_t) * (1.0 + nu_t)
    du = dr_t * (1.0 + nu_t) + sph.r0 * (nu_t - sph.nu0)
    return (du + 2.0 * sph.u0 * np.sin(0.5 * e0) ** 2) * (u_t + c)


@dataclass
class _Solution:
    """Solved rays: apparent elevation, ``tau`` at both ends, the integrals and partials.

    NaN where a ray was not solved.
    """

    e0: Array
    tau0: Array
    tau_t: Array
    c: Array
    theta: Array
    length: Array
    theta_e: Array  # d theta / d e0 at fixed tau_t
    length_e: Array  # d L / d e0 at fixed tau_t
    f_theta_t: Array  # c / (r u u') at tau_t
    f_length_t: Array  # n / u' at tau_t
    r_t: Array
    du_t: Array
    u_t: Array


def _partials(sph: _Sphere, e0: Array, tau_t: Array) -> tuple[Array, Array, Array, _Integrals]:
    """``tau0``, ``c``, the integrals and ``d(theta, L)/d e0`` ``(2, n)`` at fixed ``tau_t``.

    ``d tau0 / d e0 = c`` and ``d c / d e0 = -tau0``, so
    ``d theta / d e0 = -c f_theta(tau0) - tau0 dtheta/dc`` (and the same for ``L``).
    """
    c = sph.u0 * np.cos(e0)
    tau0 = sph.u0 * np.sin(e0)
    q = _integrate(sph, tau0, tau_t, c, derivatives=True)
    f_theta0 = c / (sph.r0 * sph.u0 * sph.du0)
    f_length0 = (1.0 + sph.nu0) / sph.du0
    theta_e = -c * f_theta0 - tau0 * q.theta_c
    length_e = -c * f_length0 - tau0 * q.length_c
    return tau0, c, np.stack([theta_e, length_e]), q


class _Collector:
    """The fields of a :class:`_Solution`, filled in as the points of a Newton solve converge."""

    def __init__(self, n: int) -> None:
        self.fields = {name: np.full(n, np.nan) for name in _Solution.__dataclass_fields__}

    def store(self, index: NDArray[np.intp], sph: _Sphere, e0: Array, tau_t: Array, q: _Integrals,
              d_e: Array, step_e: Array, step_t: Array) -> None:
        """Store converged points.

        Their integrals and partials belong to the state before the last (tiny)
        Newton step ``(step_e, step_t)``: the integrals get its first-order update.
        """
        values = {
            "e0": e0, "tau0": sph.u0 * np.sin(e0), "tau_t": tau_t, "c": sph.u0 * np.cos(e0),
            "theta": q.theta + d_e[0] * step_e + q.f_theta_t * step_t,
            "length": q.length + d_e[1] * step_e + q.f_length_t * step_t,
            "theta_e": d_e[0], "length_e": d_e[1], "f_theta_t": q.f_theta_t,
            "f_length_t": q.f_length_t, "r_t": q.r_t, "du_t": q.du_t, "u_t": q.u_t,
        }
        for name, value in values.items():
            self.fields[name][index] = value

    def solution(self) -> _Solution:
        return _Solution(**self.fields)


def _refreshed(sph: _Sphere, sol: _Solution) -> _Solution:
    """``sol`` with its integrals and partials evaluated at its own state.

    Newton stops after a step below its tolerance, which leaves the solution
    exact (the convergence is quadratic) but the partials of the state before
    that step; the Jacobians need them at the solution.
    """
    out = _Collector(sol.e0.size)
    out.fields = {name: value.copy() for name, value in vars(sol).items()}
    ok = np.isfinite(sol.e0) & np.isfinite(sol.tau_t)
    if np.any(ok):
        _, _, d_e, q = _partials(sph, sol.e0[ok], sol.tau_t[ok])
        zero = np.zeros(int(ok.sum()))
        out.store(np.flatnonzero(ok), sph, sol.e0[ok], sol.tau_t[ok], q, d_e, zero, zero)
    return out.solution()


def _take(q: _Integrals, mask: NDArray[np.bool_]) -> _Integrals:
    """The integrals of the points in ``mask``."""
    return _Integrals(**{name: None if value is None else value[mask]
                         for name, value in vars(q).items()})


def _invalidate(sol: _Solution, bad: NDArray[np.bool_]) -> None:
    """NaN in every field of ``sol`` where ``bad``."""
    if np.any(bad):
        for name, value in vars(sol).items():
            setattr(sol, name, np.where(bad, np.nan, value))


def _newton_2d(
    sph: _Sphere, e0: Array, tau_t: Array, target: Array, dr_t: Array, nu_t: Array, row: int
) -> _Solution:
    """Solve ``(theta or L)(e0, tau_t) = target`` and ``tau_t^2 = u_t^2 - c^2`` for ``(e0, tau_t)``.

    ``row`` 0 matches the central angle (a target's position), 1 the electrical
    length (a 2-D plot's range).  The Newton system's Jacobian in ``(e0, tau_t)``
    is ``[[d(theta or L)/de0, f_t], [-2 c tau0, 2 tau_t]]``; it stays regular
    where the ray arrives horizontally (``tau_t = 0``).  Each point leaves the
    iteration once its step is below the tolerances; points that do not
    converge are NaN.
    """
    out = _Collector(e0.size)
    index = np.arange(e0.size)
    for _ in range(MAX_ITERATIONS):
        tau0, c, d_e, q = _partials(sph, e0, tau_t)
        value = q.theta if row == 0 else q.length
        f_t = q.f_theta_t if row == 0 else q.f_length_t
        e1 = value - target
        e2 = tau_t**2 - _end_gap(sph, e0, c, dr_t, nu_t)
        a11, a12 = d_e[row], f_t
        a21, a22 = -2.0 * c * tau0, 2.0 * tau_t
        det = a11 * a22 - a12 * a21
        step_e = -(a22 * e1 - a12 * e2) / det
        step_t = -(a11 * e2 - a21 * e1) / det
        e0 = e0 + step_e
        tau_t = tau_t + step_t
        finite = np.isfinite(e0) & np.isfinite(tau_t)
        small = finite & (np.abs(step_e) < ELEVATION_TOLERANCE_RAD) & (
            np.abs(step_t) < TAU_TOLERANCE_M)
        if np.any(small):
            out.store(index[small], sph, e0[small], tau_t[small], _take(q, small), d_e[:, small],
                      step_e[small], step_t[small])
        keep = finite & ~small
        if not np.any(keep):
            break
        index, e0, tau_t = index[keep], e0[keep], tau_t[keep]
        target, dr_t, nu_t = target[keep], dr_t[keep], nu_t[keep]
    return out.solution()


def _newton_length(sph: _Sphere, length_m: Array, e0: Array, tau_t: Array) -> _Solution:
    """Solve ``L(e0, tau_t) = L`` for ``tau_t``, ``e0`` given (``dL/dtau_t = n_t / u'_t``)."""
    out = _Collector(e0.size)
    index = np.arange(e0.size)
    zero = np.zeros(e0.size)
    for _ in range(MAX_ITERATIONS):
        _, _, d_e, q = _partials(sph, e0, tau_t)
        step = -(q.length - length_m) / q.f_length_t
        tau_t = tau_t + step
        finite = np.isfinite(tau_t)
        small = finite & (np.abs(step) < TAU_TOLERANCE_M)
        if np.any(small):
            out.store(index[small], sph, e0[small], tau_t[small], _take(q, small), d_e[:, small],
                      zero[small], step[small])
        keep = finite & ~small
        if not np.any(keep):
            break
        index, e0, tau_t = index[keep], e0[keep], tau_t[keep]
        length_m, zero = length_m[keep], zero[keep]
    sol = out.solution()
    # The end point's radius at the solution (the collector's is the step before's).
    sol.u_t = np.hypot(sol.tau_t, sol.c)
    sol.r_t, nu_t = sph.radius(sol.u_t)
    sol.du_t = sph.du(sol.r_t, nu_t)
    return sol


def _screen(sph: _Sphere, sol: _Solution) -> Array:
    """The lowest height [m] of each ray between antenna and end point; NaN below the floor.

    A ray that descends from the antenna and rises to its end (``tau0 < 0 < tau_t``)
    is lowest where it is horizontal, ``u = c``; any other ray at one of its ends.
    Rays that reach below the floor (deep below the horizon, where the model's
    ``u`` stops growing with ``r``) are set to NaN in ``sol``.
    """
    with np.errstate(invalid="ignore"):
        lowest = np.minimum(sph.alt_m, sol.r_t - sph.radius_m)
        dips = (sol.tau0 < 0.0) & (sol.tau_t > 0.0)
    if np.any(dips):
        r_min, _ = sph.radius(np.where(dips, sol.c, sph.u0))
        lowest = np.where(dips, r_min - sph.radius_m, lowest)
    _invalidate(sol, lowest < sph.floor_height_m)
    return np.where(np.isnan(sol.e0), np.nan, lowest)


# --------------------------------------------------------------------------- Newton's start


def _path_means(sph: _Sphere, radius_m: Array, ground: Array, up: Array) -> tuple[Array, Array]:
    """Means of ``n - 1`` along a straight line from the antenna over a sphere of ``radius_m``.

    The line ends at ``(ground, up)`` in the radar's vertical plane (the antenna
    at ``alt_m`` above that sphere, heights measured from it).  Returns the mean
    weighted by ``2 (1 - s)`` at fraction ``s`` of the way (the share of the
    bending there in the elevation at the antenna) and the plain mean.
    """
    s = _PATH_NODES[:, None]
    r0 = radius_m + sph.alt_m
    nu = sph.nu(np.hypot(s * ground, s * up + r0) - radius_m)
    return _PATH_BEND_WEIGHTS @ nu, _PATH_WEIGHTS @ nu


def _effective_radius(sph: _Sphere, nu_bend: Array) -> Array:
    """The "effective earth" radius ``1 / (1/R + dn/dh)`` for a mean ``n - 1`` [m].

    A ray in an atmosphere of constant gradient ``dn/dh`` is, to first order, a
    straight line over a sphere of that radius, at the same heights (the
    classical 4/3-earth model); here ``dn/dh = -(n - 1)/H`` averaged along the
    path (:func:`_path_means`).
    """
    return 1.0 / (1.0 / sph.radius_m - nu_bend * sph.inv_h)


def _over_sphere(sph: _Sphere, radius_m: Array, theta: Array, dr_t: Array
                 ) -> tuple[Array, Array, Array]:
    """A target at central angle ``theta`` on the true sphere and ``dr_t`` above the antenna's
    radius, placed over a sphere of ``radius_m`` at the same ground distance and height:
    its ``(ground, up)`` seen from the antenna and its central angle there."""
    theta_e = theta * sph.radius_m / radius_m
    r_e = radius_m + sph.alt_m + dr_t
    return r_e * np.sin(theta_e), dr_t - 2.0 * r_e * np.sin(0.5 * theta_e) ** 2, theta_e


def _elevation_over(sph: _Sphere, radius_m: Array, chord_m: Array, dh: Array) -> Array:
    """Elevation of a straight line of length ``chord_m`` that rises ``dh`` over a sphere.

    ``(r0 + dh)^2 = r0^2 + L^2 + 2 L r0 sin(e)`` with ``r0 = radius + alt``
    (:func:`graphcal.core.frames.elevation_from_height`'s relation).
    """
    r0 = radius_m + sph.alt_m
    sin_e = (dh * (2.0 * r0 + dh) - chord_m**2) / (2.0 * chord_m * r0)
    return np.arcsin(np.clip(sin_e, -1.0, 1.0))


def _start_tau(sph: _Sphere, e0: Array, arrival: Array, dr_t: Array, nu_t: Array) -> Array:
    """``tau_t = +-sqrt(u_t^2 - c^2)`` for ``e0``, with the sign of the ``arrival`` elevation."""
    gap = _end_gap(sph, e0, sph.u0 * np.cos(e0), dr_t, nu_t)
    return np.sign(arrival) * np.sqrt(np.maximum(gap, 0.0))


# --------------------------------------------------------------------------- targets


@dataclass
class _Target:
    """Targets in the radar's vertical plane: ENU, ground distance, radius, central angle."""

    enu: Array
    ground: Array  # distance from the antenna's vertical [m]
    big_z: Array  # component along the antenna's vertical, from the centre [m]
    r_t: Array  # distance from the centre [m]
    dr_t: Array  # r_t - r0 [m]
    theta: Array  # central angle [rad]


def _target(sph: _Sphere, enu: Array) -> _Target:
    e, n, up = enu[:, 0], enu[:, 1], enu[:, 2]
    ground = np.hypot(e, n)
    big_z = up + sph.r0
    r_t = np.hypot(ground, big_z)
    # r_t^2 - r0^2 = ground^2 + up^2 + 2 up r0, divided by r_t + r0.
    dr_t = (ground**2 + up**2 + 2.0 * up * sph.r0) / (r_t + sph.r0)
    return _Target(enu, ground, big_z, r_t, dr_t, np.arctan2(ground, big_z))


def _solve_target(sph: _Sphere, tgt: _Target) -> _Solution:
    """The rays to targets (not at the antenna), screened (:func:`_screen`).

    Newton starts from a straight line over the effective earth, the path's
    gradient taken along the chord and then along that line: there the
    elevation at the target is the elevation at the antenna plus the central
    angle.  The start is within about 2e-5 rad of the apparent elevation (90 %
    of targets; 1e-4 rad at worst), so two Newton steps usually converge.
    """
    nu_t = sph.nu(tgt.dr_t + sph.alt_m)
    with np.errstate(all="ignore"):
        radius_e = _effective_radius(sph, _path_means(sph, sph.radius_m, tgt.ground,
                                                      tgt.enu[:, 2])[0])
        ground_e, up_e, _ = _over_sphere(sph, radius_e, tgt.theta, tgt.dr_t)
        radius_e = _effective_radius(sph, _path_means(sph, radius_e, ground_e, up_e)[0])
        ground_e, up_e, theta_e = _over_sphere(sph, radius_e, tgt.theta, tgt.dr_t)
        e0 = np.arctan2(up_e, ground_e)
        tau_t = _start_tau(sph, e0, e0 + theta_e, tgt.dr_t, nu_t)
        sol = _newton_2d(sph, e0, tau_t, tgt.theta, tgt.dr_t, nu_t, row=0)
        _screen(sph, sol)
        return sol


# --------------------------------------------------------------------------- public API


def _refracts(atmosphere: Atmosphere | None) -> bool:
    return atmosphere is not None and atmosphere.refracts


def _as_points(enu_m: ArrayLike) -> Array:
    enu = np.asarray(enu_m, dtype=float)
    if enu.ndim not in (1, 2) or enu.shape[-1] != 3:
        raise ValueError(f"ENU points must have shape (3,) or (n, 3), got {enu.shape}")
    return np.atleast_2d(enu)


def _straight_ray(lat_rad: float, alt_m: float, enu: Array) -> RefractedRay:
    """The straight line of sight, as a :class:`RefractedRay`."""
    radius = float(frames.gaussian_radius_m(lat_rad))
    r0 = radius + alt_m
    rng, az, el = frames.enu_to_polar(enu)
    up = enu[:, 2]
    ground = np.hypot(enu[:, 0], enu[:, 1])
    big_z = up + r0
    r_t = np.hypot(ground, big_z)
    safe = np.where(rng > 0.0, rng, 1.0)
    sin_et = np.where(rng > 0.0, (up * big_z + ground**2) / (safe * r_t), 0.0)
    # Closest approach of the segment to the centre (as simulation.simulate.earth_blocks).
    s = np.where(rng > 0.0, np.clip(-up * r0 / safe**2, 0.0, 1.0), 0.0)
    dr_t = (ground**2 + up**2 + 2.0 * up * r0) / (r_t + r0)
    return RefractedRay(
        range_m=rng,
        azimuth_rad=az,
        elevation_rad=el,
        arrival_elevation_rad=np.arcsin(np.clip(sin_et, -1.0, 1.0)),
        central_angle_rad=np.arctan2(ground, big_z),
        target_height_m=dr_t + alt_m,
        lowest_height_m=np.hypot(s * ground, s * up + r0) - radius,
    )


def refracted_ray(
    atmosphere: Atmosphere | None, lat_rad: float, alt_m: float, enu_m: ArrayLike
) -> RefractedRay:
    """The ray from a radar's antenna to targets given in its ENU frame.

    Parameters
    ----------
    atmosphere : Atmosphere or None
        The atmosphere; ``None`` or ``n_s == 0``: straight lines of sight
        (exactly :func:`graphcal.core.frames.enu_to_polar`).
    lat_rad : float
        Radar latitude [rad]: fixes the local earth sphere's radius.
    alt_m : float
        Antenna height above the ellipsoid [m].
    enu_m : array_like, shape (n, 3) or (3,)
        Targets in the radar's ENU frame [m].

    Returns
    -------
    RefractedRay
        Arrays of shape ``(n,)``.  A target at the antenna gets range and angles
        0.  NaN for a target whose ray would dip kilometres below the ellipsoid
        (deep below the horizon), where the model stops being usable.
    """
    enu = _as_points(enu_m)
    if not _refracts(atmosphere):
        return _straight_ray(lat_rad, alt_m, enu)
    sph = _Sphere(atmosphere, lat_rad, alt_m)
    # A target at the antenna has no ray: solve for a stand-in, then return zeros.
    at_antenna = ~np.any(enu != 0.0, axis=1)
    tgt = _target(sph, np.where(at_antenna[:, None], [0.0, 1.0, 0.0], enu))
    sol = _solve_target(sph, tgt)
    lowest = _screen(sph, sol)
    with np.errstate(invalid="ignore"):
        arrival = np.arctan2(sol.tau_t, sol.c)
    height = tgt.dr_t + sph.alt_m
    values = {
        "range_m": sol.length,
        "azimuth_rad": np.where(np.isnan(sol.e0), np.nan, frames.enu_to_polar(enu)[1]),
        "elevation_rad": sol.e0,
        "arrival_elevation_rad": arrival,
        "central_angle_rad": tgt.theta,
        "target_height_m": height,
        "lowest_height_m": lowest,
    }
    if np.any(at_antenna):
        for name in ("range_m", "azimuth_rad", "elevation_rad", "arrival_elevation_rad",
                     "central_angle_rad"):
            values[name] = np.where(at_antenna, 0.0, values[name])
        values["target_height_m"] = np.where(at_antenna, sph.alt_m, height)
        values["lowest_height_m"] = np.where(at_antenna, sph.alt_m, lowest)
    return RefractedRay(**values)


def refracted_polar(
    atmosphere: Atmosphere | None, lat_rad: float, alt_m: float, enu_m: ArrayLike
) -> tuple[Array, Array, Array]:
    """Refracted radar polar coordinates ``(range_m, azimuth_rad, elevation_rad)`` of ENU targets.

    ``range_m`` is the electrical length ``∫ n ds`` of the ray and
    ``elevation_rad`` its apparent elevation at the antenna (the contract's
    ``range_true`` and ``elevation_true`` with refraction); the azimuth is the
    straight line's.  The refracted counterpart of
    :func:`graphcal.core.frames.enu_to_polar`, which it equals for
    ``atmosphere`` ``None`` or ``n_s == 0``.  Parameters and NaN as
    :func:`refracted_ray`; each output has shape ``(n,)``.
    """
    ray = refracted_ray(atmosphere, lat_rad, alt_m, enu_m)
    return ray.range_m, ray.azimuth_rad, ray.elevation_rad


def refracted_polar_jacobian(
    atmosphere: Atmosphere | None, lat_rad: float, alt_m: float, enu_m: ArrayLike
) -> tuple[Array, Array]:
    """Refracted polar coordinates and their Jacobian in the target's ENU position.

    Returns
    -------
    polar : ndarray, shape (n, 3)
        ``(range_m, azimuth_rad, elevation_rad)`` as :func:`refracted_polar`.
    jacobian : ndarray, shape (n, 3, 3)
        ``d(range, azimuth, elevation) / d(east, north, up)``.  With ``q`` the
        target seen from the sphere's centre (``r_t = |q|``, ``rho`` its distance
        from the antenna's vertical, ``Z = up + r0``), ``theta_t = atan2(rho, Z)``::

            d r_t / d enu     = q / r_t
            d theta_t / d enu = (Z e / (rho r_t^2), Z n / (rho r_t^2), -rho / r_t^2)
            d L / d enu       = c d theta_t / d enu + (tau_t / r_t) d r_t / d enu   (eikonal)
            d e0 / d enu      = (2 tau_t d theta_t - 2 u_t u'_t f_t d r_t) / det

        where ``f_t = c / (r_t u_t u'_t)`` and ``det`` is the determinant of the
        Newton system's Jacobian ``[[dtheta/de0, f_t], [-2 c tau0, 2 tau_t]]``
        (implicit differentiation of ``theta(e0, r_t) = theta_t``).  The
        azimuth row is the straight line's.  Straight lines:
        :func:`graphcal.core.frames.enu_to_polar_jacobian`.

    Raises
    ------
    ValueError
        At the zenith or the antenna (zero ground distance), where the azimuth
        is undefined.
    """
    enu = _as_points(enu_m)
    if not _refracts(atmosphere):
        polar = np.stack(frames.enu_to_polar(enu), axis=-1)
        return polar, frames.enu_to_polar_jacobian(enu)
    sph = _Sphere(atmosphere, lat_rad, alt_m)
    tgt = _target(sph, enu)
    if np.any(tgt.ground == 0.0):
        raise ValueError("azimuth Jacobian is undefined at the zenith (zero ground range)")
    sol = _solve_target(sph, tgt)
    azimuth = np.where(np.isnan(sol.e0), np.nan, frames.enu_to_polar(enu)[1])
    polar = np.stack([sol.length, azimuth, sol.e0], axis=-1)
    sol = _refreshed(sph, sol)
    e, n = enu[:, 0], enu[:, 1]
    r2 = tgt.r_t**2
    d_r = np.stack([e, n, tgt.big_z], axis=-1) / tgt.r_t[:, None]
    d_theta = np.stack(
        [tgt.big_z * e / (tgt.ground * r2), tgt.big_z * n / (tgt.ground * r2), -tgt.ground / r2],
        axis=-1)
    g2 = tgt.ground**2
    d_az = np.stack([n / g2, -e / g2, np.zeros_like(e)], axis=-1)
    d_length = sol.c[:, None] * d_theta + (sol.tau_t / tgt.r_t)[:, None] * d_r
    det = 2.0 * (sol.theta_e * sol.tau_t + sol.f_theta_t * sol.c * sol.tau0)
    de_dtheta = 2.0 * sol.tau_t / det
    de_dr = -2.0 * sol.u_t * sol.du_t * sol.f_theta_t / det
    d_e0 = de_dtheta[:, None] * d_theta + de_dr[:, None] * d_r
    return polar, np.stack([d_length, d_az, d_e0], axis=-2)


# --------------------------------------------------------------------------- inverses


def _polar_args(*values: ArrayLike) -> list[Array]:
    arrays = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, dtype=float)) for v in values))
    return [np.ascontiguousarray(a).ravel() for a in arrays]


def _solve_length(sph: _Sphere, length_m: Array, e0: Array) -> _Solution:
    """The point at electrical length ``L`` along the ray of apparent elevation ``e0``.

    Newton on ``tau_t`` starts from the straight line over the effective earth
    (:func:`_effective_radius`; the path ``L / (1 + mean(n - 1))`` long).
    """
    with np.errstate(all="ignore"):
        radius_e = sph.radius_m
        chord = length_m
        for _ in range(2):
            nu_bend, nu_mean = _path_means(sph, radius_e, chord * np.cos(e0),
                                           chord * np.sin(e0))
            radius_e = _effective_radius(sph, nu_bend)
            chord = length_m / (1.0 + nu_mean)
        r0_e = radius_e + sph.alt_m
        ground, big_z = chord * np.cos(e0), chord * np.sin(e0) + r0_e
        height = np.hypot(ground, big_z) - radius_e
        arrival = e0 + np.arctan2(ground, big_z)
        tau_t = (sph.radius_m + height) * (1.0 + sph.nu(height)) * np.sin(arrival)
        sol = _newton_length(sph, length_m, e0, tau_t)
        _screen(sph, sol)
        return sol


def target_from_refracted(
    atmosphere: Atmosphere | None,
    lat_rad: float,
    alt_m: float,
    range_m: ArrayLike,
    azimuth_rad: ArrayLike,
    elevation_rad: ArrayLike,
) -> Array:
    """ENU position [m] ``(n, 3)`` of targets seen at refracted polar coordinates.

    The inverse of :func:`refracted_polar`: the point at electrical length
    ``range_m`` along the ray that leaves the antenna at apparent elevation
    ``elevation_rad`` and azimuth ``azimuth_rad`` (Newton on ``tau_t`` in
    ``L(tau_t) = range_m``).  Straight lines
    (:func:`graphcal.core.frames.polar_to_enu`) for ``atmosphere`` ``None`` or
    ``n_s == 0``.  NaN where the ray dips kilometres below the ellipsoid.

    Raises
    ------
    ValueError
        If any range is negative.
    """
    return target_from_refracted_jacobian(
        atmosphere, lat_rad, alt_m, range_m, azimuth_rad, elevation_rad, jacobian=False)[0]


def target_from_refracted_jacobian(
    atmosphere: Atmosphere | None,
    lat_rad: float,
    alt_m: float,
    range_m: ArrayLike,
    azimuth_rad: ArrayLike,
    elevation_rad: ArrayLike,
    *,
    jacobian: bool = True,
) -> tuple[Array, Array | None]:
    """:func:`target_from_refracted` and ``d(east, north, up) / d(range, azimuth, elevation)``.

    Returns
    -------
    enu : ndarray, shape (n, 3)
        Target positions [m].
    jacobian : ndarray, shape (n, 3, 3), or None
        ``d enu / d(L, az, e0)`` (``None`` when ``jacobian`` is false), the
        inverse of :func:`refracted_polar_jacobian`'s.  Along the ray
        ``dtau_t = (dL - dL/de0 de0) / f_L`` (``f_L = n_t / u'_t``); then
        ``dtheta = dtheta/de0 de0 + f_theta dtau_t`` and
        ``dr_t = (tau_t dtau_t - c tau0 de0) / (u_t u'_t)``, mapped to ENU through
        ``rho = r_t sin(theta)``, ``up = r_t cos(theta) - r0``.  Straight lines:
        :func:`graphcal.core.frames.polar_to_enu_jacobian`.

    Raises
    ------
    ValueError
        If any range is negative.
    """
    length, az, e0 = _polar_args(range_m, azimuth_rad, elevation_rad)
    if np.any(length < 0):
        raise ValueError("range must be non-negative")
    if not _refracts(atmosphere):
        enu = frames.polar_to_enu(length, az, e0)
        return enu, (frames.polar_to_enu_jacobian(length, az, e0) if jacobian else None)
    sph = _Sphere(atmosphere, lat_rad, alt_m)
    sol = _solve_length(sph, length, e0)
    sin_th, cos_th = np.sin(sol.theta), np.cos(sol.theta)
    rho = sol.r_t * sin_th
    up = (sol.r_t - sph.r0) - 2.0 * sol.r_t * np.sin(0.5 * sol.theta) ** 2
    sa, ca = np.sin(az), np.cos(az)
    enu = np.stack([rho * sa, rho * ca, up], axis=-1)
    # A zero range is the antenna itself, whatever the angles.
    enu = np.where((length == 0.0)[:, None], 0.0, enu)
    if not jacobian:
        return enu, None
    sol = _refreshed(sph, sol)
    sin_th, cos_th = np.sin(sol.theta), np.cos(sol.theta)
    rho = sol.r_t * sin_th
    # d(theta, r_t) / d(L, e0).
    uu = sol.u_t * sol.du_t
    dtau_dl = 1.0 / sol.f_length_t
    dtau_de = -sol.length_e / sol.f_length_t
    dth_dl = sol.f_theta_t * dtau_dl
    dth_de = sol.theta_e + sol.f_theta_t * dtau_de
    dr_dl = sol.tau_t * dtau_dl / uu
    dr_de = (sol.tau_t * dtau_de - sol.c * sol.tau0) / uu
    # d(rho, up) / d(theta, r_t) = [[r_t cos, sin], [-r_t sin, cos]].
    drho_dl = sol.r_t * cos_th * dth_dl + sin_th * dr_dl
    drho_de = sol.r_t * cos_th * dth_de + sin_th * dr_de
    dup_dl = -sol.r_t * sin_th * dth_dl + cos_th * dr_dl
    dup_de = -sol.r_t * sin_th * dth_de + cos_th * dr_de
    zero = np.zeros_like(rho)
    rows = [
        [sa * drho_dl, rho * ca, sa * drho_de],
        [ca * drho_dl, -rho * sa, ca * drho_de],
        [dup_dl, zero, dup_de],
    ]
    return enu, np.stack([np.stack(row, axis=-1) for row in rows], axis=-2)


def _solve_height(sph: _Sphere, length_m: Array, height_m: Array) -> _Solution:
    """The rays of electrical length ``L`` that end at ``height_m``.

    Newton starts from the straight line over the effective earth
    (:func:`_effective_radius`) that rises from the antenna to ``height_m``
    over a path ``L / (1 + mean(n - 1))`` long.
    """
    dh = height_m - sph.alt_m
    nu_t = sph.nu(height_m)
    with np.errstate(all="ignore"):
        radius_e = sph.radius_m
        chord = length_m
        e0 = _elevation_over(sph, radius_e, chord, dh)
        for _ in range(2):
            nu_bend, nu_mean = _path_means(sph, radius_e, chord * np.cos(e0),
                                           chord * np.sin(e0))
            radius_e = _effective_radius(sph, nu_bend)
            chord = length_m / (1.0 + nu_mean)
            e0 = _elevation_over(sph, radius_e, chord, dh)
        ground = chord * np.cos(e0)
        arrival = e0 + np.arctan2(ground, chord * np.sin(e0) + radius_e + sph.alt_m)
        tau_t = _start_tau(sph, e0, arrival, dh, nu_t)
        sol = _newton_2d(sph, e0, tau_t, length_m, dh, nu_t, row=1)
        _screen(sph, sol)
        return sol


def apparent_elevation_from_height(
    atmosphere: Atmosphere | None,
    lat_rad: float,
    alt_m: float,
    range_m: ArrayLike,
    target_height_m: ArrayLike,
) -> Array:
    """Apparent elevation [rad] of targets at electrical range ``range_m`` and a known height.

    For 2-D radars, which do not measure elevation: the target's height above
    the ellipsoid (from Mode C or ADS-B) fixes it.  Solves
    ``L(e0, tau_t) = range_m`` with ``tau_t^2 = u_t^2 - c^2`` (``u_t`` from the
    height) by Newton's method.  Straight lines
    (:func:`graphcal.core.frames.elevation_from_height`, the same sphere) for
    ``atmosphere`` ``None`` or ``n_s == 0``.  NaN where no ray of that
    electrical length reaches that height (or only one dipping kilometres
    below the ellipsoid).
    """
    length, height = _polar_args(range_m, target_height_m)
    if not _refracts(atmosphere):
        return frames.elevation_from_height(length, height, lat_rad, alt_m)
    sph = _Sphere(atmosphere, lat_rad, alt_m)
    return _solve_height(sph, length, height).e0


def apparent_elevation_from_height_jacobian(
    atmosphere: Atmosphere | None,
    lat_rad: float,
    alt_m: float,
    range_m: ArrayLike,
    target_height_m: ArrayLike,
) -> tuple[Array, Array, Array]:
    """:func:`apparent_elevation_from_height` and its derivatives.

    Returns
    -------
    elevation_rad : ndarray
        Apparent elevation ``e0`` [rad].
    d_elevation_d_range : ndarray
        ``d e0 / d L`` at fixed height [rad/m]: ``2 tau_t / det``.
    d_elevation_d_height : ndarray
        ``d e0 / d h_t`` at fixed electrical range [rad/m]:
        ``-2 u_t u'_t f_L / det``, with ``f_L = n_t / u'_t`` and ``det`` the
        determinant of ``[[dL/de0, f_L], [-2 c tau0, 2 tau_t]]`` (implicit
        differentiation of ``L(e0, tau_t) = L``, ``tau_t^2 + c^2 = u_t^2``).

    Straight lines: ``-tau_t / (c L)`` and ``r_t / (L c)`` with
    ``tau_t = r0 sin e0 + L`` and ``c = r0 cos e0``, the derivatives of
    ``(R + h_t)^2 = r0^2 + L^2 + 2 L r0 sin e0``.
    """
    length, height = _polar_args(range_m, target_height_m)
    if not _refracts(atmosphere):
        e0 = frames.elevation_from_height(length, height, lat_rad, alt_m)
        radius = float(frames.gaussian_radius_m(lat_rad))
        r0 = radius + alt_m
        c = r0 * np.cos(e0)
        with np.errstate(invalid="ignore", divide="ignore"):
            d_dl = -(r0 * np.sin(e0) + length) / (c * length)
            d_dh = (radius + height) / (length * c)
        return e0, d_dl, d_dh
    sph = _Sphere(atmosphere, lat_rad, alt_m)
    sol = _solve_height(sph, length, height)
    e0 = sol.e0
    sol = _refreshed(sph, sol)
    with np.errstate(invalid="ignore", divide="ignore"):
        det = 2.0 * (sol.length_e * sol.tau_t + sol.f_length_t * sol.c * sol.tau0)
        d_dl = 2.0 * sol.tau_t / det
        d_dh = -2.0 * sol.u_t * sol.du_t * sol.f_length_t / det
    return e0, d_dl, d_dh
