"""Transfer-function identification of the quadcopter's command responses
(003_691aa933e2e3c7e2.txt, Section 3.3).

The thesis fits three low-order models, each with an integrator and an input delay ``Td``,
to impulse responses in MATLAB's System Identification Toolbox:

* ``"two_poles"``    G(s) = K e^{-Td s} / (s (1 + Tp1 s)(1 + Tp2 s))         thrust -> altitude
  (3.3.1)
* ``"second_order"`` G(s) = K e^{-Td s} / (s (1 + 2 zeta Tw s + (Tw s)^2))  pitch -> position
  (3.3.2)
* ``"one_pole"``     G(s) = K e^{-Td s} / (s (1 + Tp1 s))                    yaw rate -> heading
  (3.3.3)

Method (:func:`fit_transfer_function`)
--------------------------------------
* **Input convention.** ``u[k]`` is held constant on ``[t[k], t[k+1])`` (zero-order hold,
  as a sampled command is), the system is at rest at ``t[0]`` and the input is zero before
  ``t[0]``. The model output is ``y_hat[k] = offset + K g(t[k])`` where ``g`` is the
  unit-gain response; ``offset`` (the output level at rest, e.g. hover altitude) is fitted
  too unless ``fit_offset=False``.
* **Exact delay.** ``Td = (d + f) dt`` with ``d`` integer and ``0 <= f < 1``. The delayed
  zero-order-hold input switches inside each sample interval, so the discretisation splits
  the interval exactly (modified z-transform): over ``[k dt, (k+1) dt)``

      x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1],
      Gamma0 = Gamma((1-f) dt),  Gamma1 = Phi((1-f) dt) Gamma(f dt),

  with ``Phi(h) = e^{A h}``, ``Gamma(h) = int_0^h e^{A s} ds B`` from one matrix exponential
  of the augmented ``[[A, B], [0, 0]]``. This is the continuous system driven by the exactly
  delayed piecewise-constant input, sampled at ``t[k]``: no Pade approximation, no grid
  refinement, and the residual is continuously differentiable in ``Td``.
* **Simulation.** The candidate is discretised once per evaluation and filtered with
  :func:`scipy.signal.lfilter`: the stable block (order 1 or 2) as one first- or
  second-order recursion per state (its adjugate numerators; no polynomial of the whole
  third-order model is formed, so near-equal poles and the integrator's pole at z = 1 stay
  well conditioned), then the integrator as a cumulative sum.
* **Fit.** Bounded nonlinear least squares (:func:`scipy.optimize.least_squares`, ``trf``)
  from ``n_starts`` starting points: one deterministic heuristic start plus ``n_starts - 1``
  drawn from ``rng`` (log-uniform time constants), each with ``K`` and ``offset`` initialised
  by linear least squares (they enter linearly). The lowest cost wins.
  The pieces are module-level functions of one ``_Problem`` (data, form, free and fixed
  parameters): ``_residual``, ``_multistart``, ``_jacobian``, ``_covariance``.
* **Fit percent.** ``nrmse`` is MATLAB's "fit to estimation data" (:func:`fit_percent`),
  ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` (100 = perfect, 0 = no better than the mean,
  can be negative).
* **Confidence intervals.** From the Jacobian ``J`` of the residuals at the optimum (central
  differences; one-sided at an active bound), ``Cov = s^2 (J^T J)^{-1}`` with
  ``s^2 = ||r||^2 / (n - p)``, half-width ``t_{n-p}((1+confidence)/2) sqrt(Cov_ii)``
  (Student t). ``(J^T J)^{-1}`` is taken from an SVD of the column-scaled Jacobian;
  directions with singular value below ``1e-9`` of the largest are treated as
  unidentifiable and every parameter with a visible component in them gets an infinite
  interval. The intervals assume white output noise; coloured noise (e.g. a Kalman-filtered
  position) makes them optimistic.
* **Identifiability rule** (:func:`is_identifiable`). A free parameter ``p`` is flagged
  ``identifiable[p] = False`` when its interval is infinite (rank-deficient Jacobian) or its
  half-width exceeds ``rel_tol * max(|p|, floor_p)`` with ``floor_p = dt`` for the time parameters
  (``Tp1, Tp2, Tw, Td``) and 0 for ``K`` and ``zeta``. The floor means a delay known to
  within ``rel_tol * dt`` counts as identified even when it is near zero. Strongly
  correlated estimates (``|rho| > 0.95``) are listed in ``TransferFit.correlated``: a small
  delay against a small pole shows up as a pair with rho near -1 and both flagged, because
  only their sum is determined. Fixed parameters (``fixed=``) get a zero-width interval and
  ``identifiable = True`` (they are not estimated) and are listed in ``TransferFit.fixed``.
* **Sampling.** ``t`` must be uniform (relative spread of ``diff(t)`` <= 1e-6); uneven
  samples raise ``ValueError`` rather than being resampled silently. Resample first (the
  thesis itself interpolates onto a 0.05 s grid before identification, Appendix C).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy import linalg, optimize, signal, stats

from estimator._checks import check_array, check_increasing_times, check_int, check_real

__all__ = [
    "FORMS",
    "AxisIdentification",
    "TransferFit",
    "check_responses",
    "equivalent_lag",
    "fit_percent",
    "fit_transfer_function",
    "identify_axes",
    "is_identifiable",
    "simulate",
    "step_response",
    "total_lag",
]

#: Parameter names of each model form (order used in arrays).
FORMS: dict[str, tuple[str, ...]] = {
    "two_poles": ("K", "Tp1", "Tp2", "Td"),
    "second_order": ("K", "Tw", "zeta", "Td"),
    "one_pole": ("K", "Tp1", "Td"),
}
_TIME_PARAMS = frozenset({"Tp1", "Tp2", "Tw", "Td"})
_UNIFORM_RTOL = 1e-6
_SVD_RTOL = 1e-9
_CORRELATED = 0.95


@dataclass(frozen=True, eq=False)
class TransferFit:
    """Result of :func:`fit_transfer_function`.

    ``params``: best estimate per parameter of the form (K in output units per input unit
    per second; time constants and delay in seconds; zeta dimensionless).
    ``intervals``: ``(low, high)`` confidence interval per parameter at ``confidence``.
    ``identifiable``: per-parameter flag (rule in the module docstring).
    ``nrmse``: not an error but MATLAB's fit percent ("fit to estimation data", named
    after MATLAB's NRMSE fit), ``100 (1 - ||y - y_hat|| / ||y - mean y||)``: 100 = perfect
    fit, 0 = no better than the mean of y, negative = worse; higher is better.
    ``status``: ``"ok"``, or ``"not_converged"`` when no start converged, or
    ``"at_bound"`` when the best estimate has a free parameter on a bound (``at_bound``).
    ``covariance``: (p, p) parameter covariance over ``estimated`` (the free parameters in
    form order, then ``"offset"`` when fitted); a pseudo-inverse when the Jacobian is rank
    deficient (those parameters then have infinite ``intervals``). ``t_quantile``: the
    Student-t factor of the intervals. ``correlated``: pairs with ``|rho| > 0.95``.
    """

    form: str
    params: dict[str, float]
    nrmse: float
    intervals: dict[str, tuple[float, float]]
    identifiable: dict[str, bool]
    status: str
    offset: float
    stderr: dict[str, float]
    correlation: dict[tuple[str, str], float]
    correlated: tuple[tuple[str, str, float], ...]
    covariance: np.ndarray
    estimated: tuple[str, ...]
    t_quantile: float
    fixed: tuple[str, ...]
    at_bound: tuple[str, ...]
    confidence: float
    dt: float
    residual_std: float
    y_hat: np.ndarray = field(repr=False)
    n_starts: int = 0
    nfev: int = 0
    elapsed_s: float = 0.0
    message: str = ""

    def simulate(self, t: np.ndarray, u: np.ndarray, *, with_offset: bool = True) -> np.ndarray:
        """Response of the identified model to ``u`` (ZOH) on the uniform grid ``t``, (n,)."""
        y = simulate(t, u, self.form, self.params)
        return y + self.offset if with_offset else y

    def step_response(self, t: np.ndarray) -> np.ndarray:
        """Response to a unit step at ``t[0]`` on the uniform grid ``t`` (no offset), (n,)."""
        return step_response(t, self.form, self.params)


# --------------------------------------------------------------------------- validation

def _check_form(form: str) -> tuple[str, ...]:
    if not isinstance(form, str) or form not in FORMS:
        raise ValueError(f"form: must be one of {sorted(FORMS)}, got {form!r}")
    return FORMS[form]


def _check_grid(t: np.ndarray) -> float:
    t = check_increasing_times(t, "t", min_size=2)
    dts = np.diff(t)
    dt = (t[-1] - t[0]) / (t.size - 1)
    spread = float(np.max(np.abs(dts - dt)) / dt)
    if spread > _UNIFORM_RTOL:
        raise ValueError(f"t: sample spacing must be uniform (relative spread {spread:.3g} > "
                         f"{_UNIFORM_RTOL:g}); resample onto a uniform grid first")
    return float(dt)


def _check_signal(name: str, x: np.ndarray, n: int) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.shape != (n,):
        raise ValueError(f"{name}: must have shape ({n},) like t, got {x.shape}")
    if not np.all(np.isfinite(x)):
        i = int(np.argmax(~np.isfinite(x)))
        raise ValueError(f"{name}: contains non-finite values (first at index {i}: {x[i]!r})")
    return x


def _check_params(form: str, params: dict[str, float]) -> dict[str, float]:
    names = _check_form(form)
    missing = [k for k in names if k not in params]
    if missing:
        raise ValueError(f"params: missing {missing} for form {form!r}")
    p = {k: float(params[k]) for k in names}
    for k, v in p.items():
        if not np.isfinite(v):
            raise ValueError(f"params[{k!r}]: must be finite, got {v!r}")
        if k in ("Tp1", "Tp2", "Tw", "zeta") and v <= 0:
            raise ValueError(f"params[{k!r}]: must be > 0, got {v!r}")
        if k == "Td" and v < 0:
            raise ValueError(f"params['Td']: must be >= 0, got {v!r}")
    return p


# --------------------------------------------------------------------------- simulation

def _state_space(form: str, p: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """Unit-gain realisation: stable block first, the integrator (output) last.

    two_poles: cascade lag(Tp1) -> lag(Tp2) -> integrator; second_order: companion form of
    1/(Tw^2 s^2 + 2 zeta Tw s + 1) -> integrator; one_pole: lag(Tp1) -> integrator.
    """
    if form == "two_poles":
        a1, a2 = 1.0 / p["Tp1"], 1.0 / p["Tp2"]
        A = np.array([[-a1, 0.0, 0.0], [a2, -a2, 0.0], [0.0, 1.0, 0.0]])
        B = np.array([a1, 0.0, 0.0])
    elif form == "second_order":
        w2 = 1.0 / p["Tw"] ** 2
        A = np.array([[0.0, 1.0, 0.0], [-w2, -2.0 * p["zeta"] / p["Tw"], 0.0], [1.0, 0.0, 0.0]])
        B = np.array([0.0, w2, 0.0])
    else:  # one_pole
        a1 = 1.0 / p["Tp1"]
        A = np.array([[-a1, 0.0], [1.0, 0.0]])
        B = np.array([a1, 0.0])
    return A, B


def _zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Phi(h) = e^{A h} and Gamma(h) = int_0^h e^{A s} ds B via one augmented expm."""
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = A * h
    M[:n, n] = B * h
    E = linalg.expm(M)
    return E[:n, :n], E[:n, n]


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    """x delayed by k >= 0 samples, zeros in front, same length."""
    if k == 0:
        return x
    out = np.zeros_like(x)
    if k < x.size:
        out[k:] = x[: x.size - k]
    return out


def _unit_response(form: str, p: dict[str, float], dt: float, u: np.ndarray) -> np.ndarray:
    """Sampled response of the unit-gain model with exact input delay to ZOH input u."""
    A, B = _state_space(form, p)
    n = A.shape[0]
    D = p["Td"] / dt
    d = int(np.floor(D))
    f = D - d
    if f < 1e-12:
        f = 0.0
    if f == 0.0:
        Phi, G0 = _zoh(A, B, dt)
        G1 = np.zeros(n)
    else:
        Phi_a, G0 = _zoh(A, B, (1.0 - f) * dt)
        Phi_b, Gb = _zoh(A, B, f * dt)
        Phi = Phi_a @ Phi_b
        G1 = Phi_a @ Gb
    ud = _shift(u, d)
    ud1 = _shift(ud, 1)
    W = np.outer(G0, ud) + np.outer(G1, ud1)  # (n, N): input term of x[k+1]
    m = n - 1
    if m == 1:
        xs = signal.lfilter([0.0, 1.0], [1.0, -Phi[0, 0]], W[0])[None, :]
    else:
        p11, p12, p21, p22 = Phi[0, 0], Phi[0, 1], Phi[1, 0], Phi[1, 1]
        den = [1.0, -(p11 + p22), p11 * p22 - p12 * p21]
        W0p, W1p = _shift(W[0], 1), _shift(W[1], 1)
        # X = adj(zI - Phi_s) W / det(zI - Phi_s), row by row
        r0 = W[0] - p22 * W0p + p12 * W1p
        r1 = W[1] - p11 * W1p + p21 * W0p
        xs = np.vstack([signal.lfilter([0.0, 1.0], den, r0),
                        signal.lfilter([0.0, 1.0], den, r1)])
    inc = Phi[m, :m] @ xs + W[m]  # y[k+1] - y[k]
    y = np.empty_like(u)
    y[0] = 0.0
    np.cumsum(inc[:-1], out=y[1:])
    return y


def simulate(t: np.ndarray, u: np.ndarray, form: str, params: dict[str, float]) -> np.ndarray:
    """Sampled response ``y (n,)`` of ``K e^{-Td s}/(s D(s))`` to the ZOH input ``u (n,)``.

    ``t`` (n,) uniform grid in seconds; the system is at rest at ``t[0]`` with zero input
    before it; the delay is applied exactly (module docstring). Section 3.3 forms.
    """
    names = _check_form(form)
    dt = _check_grid(t)
    u = _check_signal("u", u, np.asarray(t).size)
    p = _check_params(form, params)
    del names
    return p["K"] * _unit_response(form, p, dt, u)


def step_response(t: np.ndarray, form: str, params: dict[str, float]) -> np.ndarray:
    """Response ``(n,)`` to a unit step applied at ``t[0]`` (Figs 3.15, 3.18, 3.21)."""
    t = np.asarray(t, dtype=float)
    return simulate(t, np.ones_like(t), form, params)


# --------------------------------------------------------------------------- fitting

def _default_bounds(names: tuple[str, ...], dt: float, span: float) -> dict[str, tuple]:
    b: dict[str, tuple[float, float]] = {}
    for k in names:
        if k == "K":
            b[k] = (-np.inf, np.inf)
        elif k in ("Tp1", "Tp2", "Tw"):
            b[k] = (1e-3 * dt, 10.0 * span)
        elif k == "zeta":
            b[k] = (1e-3, 10.0)
        else:  # Td
            b[k] = (0.0, 0.5 * span)
    return b


def _merge_bounds(names, defaults, bounds, dt, span) -> dict[str, tuple[float, float]]:
    out = dict(defaults)
    if bounds is None:
        return out
    if not isinstance(bounds, dict):
        raise ValueError(  # noqa: TRY004 (project convention: bad input is ValueError)
            f"bounds: must be a dict name -> (low, high), got {type(bounds).__name__}")
    for k, v in bounds.items():
        if k not in names:
            raise ValueError(f"bounds: unknown parameter {k!r} for this form (have {names})")
        try:
            lo, hi = (float(v[0]), float(v[1]))
        except (TypeError, IndexError, ValueError):
            raise ValueError(f"bounds[{k!r}]: must be a (low, high) pair, got {v!r}") from None
        if not lo < hi:
            raise ValueError(f"bounds[{k!r}]: low must be < high, got {(lo, hi)}")
        if k in ("Tp1", "Tp2", "Tw", "zeta") and lo <= 0:
            raise ValueError(f"bounds[{k!r}]: low must be > 0, got {lo!r}")
        if k == "Td" and (lo < 0 or not np.isfinite(hi) or hi >= span):
            raise ValueError(f"bounds['Td']: must satisfy 0 <= low < high < record length "
                             f"{span:g} s, got {(lo, hi)}")
        if k != "K" and not np.isfinite(hi):
            raise ValueError(f"bounds[{k!r}]: high must be finite, got {hi!r}")
        out[k] = (lo, hi)
    return out


def _starts(names_free, bnds, dt, span, n_starts, rng) -> list[dict[str, float]]:
    """Deterministic heuristic start, then rng draws (log-uniform time constants)."""
    def clip(k, v):
        lo, hi = bnds[k]
        return float(min(max(v, lo), hi))

    def lim(k, lo_pref, hi_pref):
        lo, hi = bnds[k]
        a, b = max(lo, lo_pref), min(hi, hi_pref)
        return (a, b) if a < b else (lo, hi)

    first = {"Tp1": span / 20, "Tp2": span / 8, "Tw": span / 10, "zeta": 0.7, "Td": dt}
    out = [{k: clip(k, first[k]) for k in names_free if k != "K"}]
    for _ in range(n_starts - 1):
        s = {}
        for k in names_free:
            if k == "K":
                continue
            if k in ("Tp1", "Tp2", "Tw"):
                a, b = lim(k, dt / 2, span)
                s[k] = float(np.exp(rng.uniform(np.log(a), np.log(b))))
            elif k == "zeta":
                a, b = lim(k, 0.1, 2.0)
                s[k] = float(np.exp(rng.uniform(np.log(a), np.log(b))))
            else:
                a, b = lim(k, 0.0, span / 4)
                s[k] = float(rng.uniform(a, b))
        out.append(s)
    return out


@dataclass(frozen=True, eq=False)
class _Problem:
    """One fitting problem: data, form, which parameters are free, fixed or linear."""

    form: str
    names: tuple[str, ...]
    dt: float
    u: np.ndarray
    y: np.ndarray
    fixed: dict[str, float]
    free: tuple[str, ...]      # estimated model parameters, "K" first when free
    fit_offset: bool

    @property
    def k_free(self) -> bool:
        return "K" not in self.fixed

    @property
    def free_nl(self) -> tuple[str, ...]:
        """Free parameters other than K (the ones the residual is nonlinear in)."""
        return self.free[1:] if self.k_free else self.free


def _unpack(prob: _Problem, x: np.ndarray) -> tuple[dict[str, float], float]:
    """Parameter vector ``x`` (free parameters in ``prob.free`` order, then the offset) ->
    (all model parameters, offset)."""
    p = dict(prob.fixed)
    for i, k in enumerate(prob.free):
        p[k] = x[i]
    off = x[len(prob.free)] if prob.fit_offset else 0.0
    return p, off


def _residual(x: np.ndarray, prob: _Problem) -> np.ndarray:
    """Model minus data, (n,): ``offset + K g(t; p) - y`` (g: unit-gain response)."""
    p, off = _unpack(prob, x)
    return off + p["K"] * _unit_response(prob.form, p, prob.dt, prob.u) - prob.y


def _initial_vector(prob: _Problem, start: dict[str, float], lo: np.ndarray,
                    hi: np.ndarray) -> np.ndarray:
    """Start vector for the nonlinear parameters ``start``; K and the offset enter linearly,
    so they are initialised by linear least squares at that start."""
    n = prob.y.size
    g = _unit_response(prob.form, {**prob.fixed, **start, "K": 1.0}, prob.dt, prob.u)
    cols = []
    if prob.k_free:
        cols.append(g)
    if prob.fit_offset:
        cols.append(np.ones(n))
    target = prob.y - (0.0 if prob.k_free else prob.fixed["K"] * g)
    lin = np.linalg.lstsq(np.column_stack(cols), target, rcond=None)[0] if cols else []
    x0 = []
    if prob.k_free:
        x0.append(lin[0] if np.isfinite(lin[0]) and lin[0] != 0 else 1.0)
    x0 += [start[k] for k in prob.free_nl]
    if prob.fit_offset:
        x0.append(lin[-1])
    return np.clip(np.array(x0, dtype=float), lo, hi)


def _multistart(prob: _Problem, starts: list[dict[str, float]], lo: np.ndarray,
                hi: np.ndarray, max_nfev: int) -> tuple[optimize.OptimizeResult, int]:
    """Bounded trust-region least squares from each start; the lowest cost wins.

    Returns (best result, total residual evaluations).
    """
    best = None
    nfev = 0
    for s in starts:
        x0 = _initial_vector(prob, s, lo, hi)
        res = optimize.least_squares(_residual, x0, bounds=(lo, hi), method="trf",
                                     x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12,
                                     max_nfev=max_nfev, args=(prob,))
        nfev += res.nfev
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None
    return best, nfev


def _jacobian(prob: _Problem, x: np.ndarray, r: np.ndarray, lo: np.ndarray,
              hi: np.ndarray) -> np.ndarray:
    """(n, p) Jacobian of the residual at ``x`` by central differences (one-sided at a
    bound). Step ``1e-6 max(|x_j|, typical_j)`` with typical scale dt for time parameters,
    1e-3 for zeta, 1 for K and the offset."""
    typical = [prob.dt if k in _TIME_PARAMS else (1e-3 if k == "zeta" else 1.0)
               for k in prob.free]
    typical += [1.0] if prob.fit_offset else []
    J = np.empty((r.size, x.size))
    for j in range(x.size):
        h = 1e-6 * max(abs(x[j]), typical[j])
        xp, xm = x.copy(), x.copy()
        if x[j] + h <= hi[j] and x[j] - h >= lo[j]:
            xp[j] += h
            xm[j] -= h
            J[:, j] = (_residual(xp, prob) - _residual(xm, prob)) / (2 * h)
        elif x[j] + h <= hi[j]:
            xp[j] += h
            J[:, j] = (_residual(xp, prob) - r) / h
        else:
            xm[j] -= h
            J[:, j] = (r - _residual(xm, prob)) / h
    return J


def _covariance(J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Parameter covariance ``s^2 (J^T J)^{-1}`` (``s^2 = ||r||^2 / (n - p)``).

    The inverse comes from an SVD of the column-scaled Jacobian; directions with singular
    value below ``_SVD_RTOL`` of the largest are dropped (a pseudo-inverse) and every
    parameter with a visible component (> 1e-3) in them gets an infinite variance.
    Returns (covariance (p, p), variances (p,) with those infinities, s^2).
    """
    dof = J.shape[0] - J.shape[1]
    s2 = float(r @ r) / dof
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    _, S, Vt = np.linalg.svd(J / scale, full_matrices=False)
    ok = _SVD_RTOL * S[0] < S
    cov = s2 * ((Vt[ok].T / S[ok] ** 2) @ Vt[ok]) / np.outer(scale, scale)
    var = np.diag(cov).copy()
    if not np.all(ok):
        var[np.any(np.abs(Vt[~ok]) > 1e-3, axis=0)] = np.inf
    return cov, var, s2


def is_identifiable(value: float, half_width: float, *, floor: float = 0.0,
                    rel_tol: float = 0.25) -> bool:
    """The identifiability rule (module docstring): the interval's half-width is finite and
    at most ``rel_tol * max(|value|, floor)``; ``floor`` is dt for time parameters."""
    value = check_real(value, "value")
    half_width = check_real(half_width, "half_width", lo=0.0, finite=False)
    floor = check_real(floor, "floor", lo=0.0)
    rel_tol = check_real(rel_tol, "rel_tol", lo=0.0, lo_open=True)
    return bool(math.isfinite(half_width) and half_width <= rel_tol * max(abs(value), floor))


def fit_percent(y: np.ndarray, y_hat: np.ndarray) -> float:
    """MATLAB's "fit to estimation data", ``100 (1 - ||y - y_hat|| / ||y - mean y||)``.

    y, y_hat : (n,) data and model output. 100 = perfect, 0 = no better than the mean, can be
    negative; NaN when ``y`` is constant.
    """
    y = check_array(y, "y", shape=(None,))
    y_hat = check_array(y_hat, "y_hat", shape=(y.size,))
    if y.size == 0:
        raise ValueError("y: needs at least one sample, got shape (0,)")
    d = y - y.mean()
    scale = float(np.max(np.abs(d)))
    if not scale > 0:
        return float("nan")
    # both norms of scaled vectors, so squares of values near 1e300 do not overflow
    return float(100.0 * (1.0 - np.linalg.norm((y - y_hat) / scale)
                          / np.linalg.norm(d / scale)))


def _intervals(prob: _Problem, params: dict[str, float], sd: np.ndarray, tq: float,
               rel_tol: float) -> tuple[dict, dict, dict]:
    """Per model parameter: interval ``value +- tq sd``, identifiability flag, standard error
    (``sd`` over ``prob.free``; fixed parameters: zero width, identifiable)."""
    intervals: dict[str, tuple[float, float]] = {}
    identifiable: dict[str, bool] = {}
    stderr: dict[str, float] = {}
    for k in prob.names:
        if k in prob.fixed:
            intervals[k], identifiable[k], stderr[k] = (params[k], params[k]), True, 0.0
            continue
        j = prob.free.index(k)
        hw = tq * sd[j]
        intervals[k] = (params[k] - hw, params[k] + hw)
        stderr[k] = float(sd[j])
        identifiable[k] = not np.isnan(hw) and is_identifiable(
            params[k], hw, rel_tol=rel_tol, floor=prob.dt if k in _TIME_PARAMS else 0.0)
    return intervals, identifiable, stderr


def _correlations(free: tuple[str, ...], cov: np.ndarray) -> tuple[dict, list]:
    """Correlation of each pair of free parameters, and the pairs with ``|rho| > 0.95``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    correlation: dict[tuple[str, str], float] = {}
    correlated = []
    for i, a in enumerate(free):
        for j in range(i + 1, len(free)):
            rho = float(corr[i, j]) if np.isfinite(corr[i, j]) else float("nan")
            correlation[(a, free[j])] = rho
            if np.isfinite(rho) and abs(rho) > _CORRELATED:
                correlated.append((a, free[j], rho))
    return correlation, correlated


def _swap_poles(names, per_param, correlation, correlated, at_bound, est_names):
    """Exchange the names Tp1 and Tp2 everywhere (``per_param`` dicts in place)."""
    ren = {"Tp1": "Tp2", "Tp2": "Tp1"}
    for dct in per_param:
        dct["Tp1"], dct["Tp2"] = dct["Tp2"], dct["Tp1"]

    def pair(a, b):
        return tuple(sorted((ren.get(a, a), ren.get(b, b)), key=names.index))

    return ({pair(a, b): v for (a, b), v in correlation.items()},
            [(*pair(a, b), v) for a, b, v in correlated],
            [ren.get(k, k) for k in at_bound], [ren.get(k, k) for k in est_names])


def fit_transfer_function(
    t: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    form: str,
    *,
    bounds: dict[str, tuple[float, float]] | None = None,
    n_starts: int = 6,
    fixed: dict[str, float] | None = None,
    rng: np.random.Generator | None = None,
    fit_offset: bool = True,
    confidence: float = 0.95,
    rel_tol: float = 0.25,
    max_nfev: int = 400,
) -> TransferFit:
    """Fit ``K e^{-Td s} / (s D(s))`` of ``form`` to input ``u`` and output ``y``.

    Parameters
    ----------
    t : (n,) uniform sample times, seconds (uneven grids raise ValueError).
    u : (n,) input, held constant between samples (zero-order hold); zero before ``t[0]``.
    y : (n,) measured output (any units; ``K`` is in output units per input unit per second).
    form : ``"two_poles"`` (3.3.1 thrust), ``"second_order"`` (3.3.2 pitch),
        ``"one_pole"`` (3.3.3 yaw rate).
    bounds : optional ``{name: (low, high)}`` overriding the defaults (K free;
        Tp1, Tp2, Tw in [1e-3 dt, 10 T]; zeta in [1e-3, 10]; Td in [0, T/2]; T = record length).
    n_starts : number of starting points (>= 1): one heuristic, the rest from ``rng``.
    fixed : optional ``{name: value}`` held fixed (e.g. ``{"Td": 0.0}``).
    rng : generator for the random starts; ``None`` uses ``numpy.random.default_rng(0)``
        so that a call without one is reproducible.
    fit_offset : also fit a constant output offset (the output level at rest).
    confidence : level of the intervals, in (0, 1).
    rel_tol : identifiability threshold on the interval half-width (module docstring).
    max_nfev : evaluation budget per start.

    Returns a :class:`TransferFit`; method and rules in the module docstring.
    """
    t0 = time.perf_counter()
    prob, bnds, n_starts, rng = _check_fit_inputs(t, u, y, form, bounds, n_starts, fixed, rng,
                                                  fit_offset, confidence, rel_tol, max_nfev)
    names, dt, n = prob.names, prob.dt, prob.y.size
    span = float(dt * (n - 1))
    lo = np.array([bnds[k][0] for k in prob.free] + ([-np.inf] if fit_offset else []))
    hi = np.array([bnds[k][1] for k in prob.free] + ([np.inf] if fit_offset else []))

    starts = [{**s} for s in _starts(prob.free_nl, bnds, dt, span, n_starts, rng)]
    best, nfev = _multistart(prob, starts, lo, hi, max_nfev)

    x = best.x
    p_best, offset = _unpack(prob, x)
    r = _residual(x, prob)
    yhat = r + prob.y
    J = _jacobian(prob, x, r, lo, hi)
    cov, var, s2 = _covariance(J, r)
    tq = float(stats.t.ppf(0.5 + confidence / 2.0, n - x.size))
    params = {k: float(p_best[k]) for k in names}
    intervals, identifiable, stderr = _intervals(prob, params, np.sqrt(var), tq, rel_tol)
    correlation, correlated = _correlations(prob.free, cov)
    at_bound = [k for j, k in enumerate(prob.free)
                if (np.isfinite(lo[j]) and x[j] - lo[j] <= 1e-9 * max(1.0, abs(lo[j])))
                or (np.isfinite(hi[j]) and hi[j] - x[j] <= 1e-9 * max(1.0, abs(hi[j])))]
    est_names = [*prob.free, "offset"] if fit_offset else list(prob.free)
    if form == "two_poles" and params["Tp1"] > params["Tp2"]:
        # the form is symmetric in (Tp1, Tp2): report Tp1 <= Tp2
        correlation, correlated, at_bound, est_names = _swap_poles(
            names, (params, intervals, identifiable, stderr), correlation, correlated,
            at_bound, est_names)
    order = sorted(range(len(est_names)),
                   key=lambda i: (names + ("offset",)).index(est_names[i]))
    cov_out = cov[np.ix_(order, order)]
    est_names = [est_names[i] for i in order]
    bound = tuple(sorted(at_bound, key=names.index))
    if best.status <= 0:
        status = "not_converged"
    elif bound:
        status = "at_bound"
    else:
        status = "ok"
    return TransferFit(
        form=form, params=params, nrmse=fit_percent(prob.y, yhat), intervals=intervals,
        identifiable=identifiable, status=status, offset=float(offset), stderr=stderr,
        correlation=correlation, covariance=cov_out, estimated=tuple(est_names),
        t_quantile=tq, correlated=tuple(correlated),
        fixed=tuple(k for k in names if k in prob.fixed), at_bound=bound,
        confidence=float(confidence), dt=dt, residual_std=float(np.sqrt(s2)), y_hat=yhat,
        n_starts=int(n_starts), nfev=int(nfev), elapsed_s=time.perf_counter() - t0,
        message=str(best.message),
    )


def _check_fit_inputs(t, u, y, form, bounds, n_starts, fixed, rng, fit_offset, confidence,
                      rel_tol, max_nfev) -> tuple[_Problem, dict, int, np.random.Generator]:
    """Every check of :func:`fit_transfer_function`, before any fitting."""
    names = _check_form(form)
    dt = _check_grid(t)
    n = np.asarray(t).size
    u = _check_signal("u", u, n)
    y = _check_signal("y", y, n)
    if not np.any(u != 0):
        raise ValueError("u: input is identically zero; nothing to identify")
    n_starts = check_int(n_starts, "n_starts", lo=1)
    max_nfev = check_int(max_nfev, "max_nfev", lo=1)
    check_real(confidence, "confidence", lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    check_real(rel_tol, "rel_tol", lo=0.0, lo_open=True)
    if not isinstance(fit_offset, (bool, np.bool_)):
        raise TypeError(f"fit_offset: must be a bool, got {type(fit_offset).__name__}")
    if rng is None:
        rng = np.random.default_rng(0)
    elif not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: must be a numpy.random.Generator or None, got {type(rng).__name__}")
    span = float(dt * (n - 1))
    bnds = _merge_bounds(names, _default_bounds(names, dt, span), bounds, dt, span)
    fixed = dict(fixed or {})
    for k, v in fixed.items():
        if k not in names:
            raise ValueError(f"fixed: unknown parameter {k!r} for form {form!r} (have {names})")
        v = check_real(v, f"fixed[{k!r}]")
        lo, hi = bnds[k]
        if not lo <= v <= hi:
            raise ValueError(f"fixed[{k!r}]: must be finite and within bounds {(lo, hi)}, "
                             f"got {v!r}")
        fixed[k] = v
    free = tuple((["K"] if "K" not in fixed else []) + [k for k in names
                                                          if k != "K" and k not in fixed])
    n_par = len(free) + int(fit_offset)
    if n - n_par < 1:
        raise ValueError(f"t: {n} samples are too few for {n_par} parameters")
    prob = _Problem(form=form, names=names, dt=dt, u=u, y=y, fixed=fixed, free=free,
                    fit_offset=bool(fit_offset))
    return prob, bnds, n_starts, rng


def _lag_gradient(form: str, p: dict[str, float]) -> dict[str, float]:
    """d(total lag) / d(parameter) for :func:`total_lag`."""
    if form == "two_poles":
        return {"Td": 1.0, "Tp1": 1.0, "Tp2": 1.0}
    if form == "second_order":
        return {"Td": 1.0, "zeta": 2.0 * p["Tw"], "Tw": 2.0 * p["zeta"]}
    return {"Td": 1.0, "Tp1": 1.0}


def total_lag(form: str, params: dict[str, float]) -> float:
    """Total lag ``L = Td + D'(0)`` (seconds) of ``K e^{-Td s} / (s D(s))``, ``D(0) = 1``.

    The step response approaches the ramp ``K (t - L)``: ``L = Td + Tp1 + Tp2``
    (two_poles), ``Td + 2 zeta Tw`` (second_order) or ``Td + Tp1`` (one_pole). ``params``
    needs the form's time parameters (``K`` is not used). Section 3.3 forms.
    """
    p = _check_params(form, {"K": 1.0, **params})
    if form == "two_poles":
        return p["Td"] + p["Tp1"] + p["Tp2"]
    if form == "second_order":
        return p["Td"] + 2.0 * p["zeta"] * p["Tw"]
    return p["Td"] + p["Tp1"]


def equivalent_lag(fit: TransferFit) -> tuple[float, tuple[float, float]]:
    """Total lag of the fitted model (:func:`total_lag`) and its confidence interval (same
    level as the fit).

    ``L`` stays well determined when its parts trade off (a small delay against a small
    pole, two near-equal poles), so it is the fair quantity to compare across fits. The
    interval uses the delta method on ``TransferFit.covariance`` (the pseudo-inverse: the
    gradient of ``L`` is orthogonal to those unidentifiable directions).
    """
    lag = total_lag(fit.form, fit.params)
    grad = _lag_gradient(fit.form, fit.params)
    g = np.array([grad.get(k, 0.0) for k in fit.estimated])
    hw = fit.t_quantile * float(np.sqrt(max(g @ fit.covariance @ g, 0.0)))
    return float(lag), (float(lag - hw), float(lag + hw))


@dataclass(frozen=True, eq=False)
class AxisIdentification:
    """Everything :func:`identify_axes` computed for one axis.

    ``t, u, y``: the impulse experiment; ``clean`` / ``noisy`` / ``mc``: fits to it without
    noise, with one noise realisation ``y_noisy`` (sigma ``sigma``) and with ``n_mc``
    further ones; ``step``: the validation step ``(t, u, y)`` and ``step_pred`` the clean
    model's prediction of it, ``step_pct`` its fit percent (NaN without a step run).
    """

    axis: str
    form: str
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    clean: TransferFit
    noisy: TransferFit | None
    y_noisy: np.ndarray | None
    mc: tuple[TransferFit, ...]
    sigma: float
    step: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    step_pred: np.ndarray | None
    step_pct: float


def check_responses(data: Mapping, axes: Iterable[str]) -> dict:
    """``data`` ({(axis, kind): (t, u, y)}) as a dict, checked: each triple 1-D of one length,
    every ``(axis, "impulse")`` of ``axes`` present; ValueError naming the key otherwise."""
    data = dict(data)
    for key, triple in data.items():
        try:
            t, u, y = (np.asarray(a, dtype=float) for a in triple)
        except (TypeError, ValueError):
            raise ValueError(f"responses[{key!r}]: expected a (t, u, y) triple of arrays") \
                from None
        if not (t.ndim == 1 and t.shape == u.shape == y.shape):
            raise ValueError(f"responses[{key!r}]: t, u, y must be 1-D of one length, got "
                             f"shapes {t.shape}, {u.shape}, {y.shape}")
    for axis in axes:
        if (axis, "impulse") not in data:
            raise ValueError(f"responses: missing ({axis!r}, 'impulse')")
    return data


def _rng(seed: int, axis_index: int, run: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, axis_index, run]))


def identify_axes(data: Mapping[tuple[str, str], tuple], forms: Mapping[str, str],
                  sigmas: Mapping[str, float], *, seed: int = 0, n_mc: int = 20,
                  n_starts: int = 8, rel_tol: float = 0.25) -> dict[str, AxisIdentification]:
    """Fit each axis of ``forms`` ({axis: form}) to its impulse experiment
    ``data[(axis, "impulse")] = (t, u, y)`` (arrays (n,), SI), clean and, when
    ``sigmas[axis]`` > 0 (unit of y), with one added white-noise realisation and ``n_mc``
    further ones; an optional ``data[(axis, "step")]`` validates the clean model.
    Randomness: ``SeedSequence([seed, axis index, run])``, run 0 = the clean fit's starts,
    1 = the noisy realisation, 2.. = Monte Carlo."""
    out: dict[str, AxisIdentification] = {}
    for ai, (axis, form) in enumerate(forms.items()):
        t, u, y = (np.asarray(a, dtype=float) for a in data[(axis, "impulse")])

        def fit(yy: np.ndarray, g: np.random.Generator, t=t, u=u, form=form) -> TransferFit:
            return fit_transfer_function(t, u, yy, form, n_starts=n_starts, rng=g,
                                         rel_tol=rel_tol)

        clean = fit(y, _rng(seed, ai, 0))
        sigma = sigmas[axis]
        noisy, y_noisy, mc = None, None, []
        if sigma > 0:
            g = _rng(seed, ai, 1)
            y_noisy = y + sigma * g.standard_normal(y.size)
            noisy = fit(y_noisy, g)
            for run in range(n_mc):
                g = _rng(seed, ai, 2 + run)
                mc.append(fit(y + sigma * g.standard_normal(y.size), g))
        step = step_pred = None
        step_pct = float("nan")
        if (axis, "step") in data:
            ts, us, ys = (np.asarray(a, dtype=float) for a in data[(axis, "step")])
            step = (ts, us, ys)
            step_pred = simulate(step[0], step[1], form, clean.params) + clean.offset
            step_pct = fit_percent(step[2], step_pred)
        out[axis] = AxisIdentification(axis=axis, form=form, t=t, u=u, y=y, clean=clean,
                                       noisy=noisy, y_noisy=y_noisy, mc=tuple(mc),
                                       sigma=sigma, step=step, step_pred=step_pred,
                                       step_pct=step_pct)
    return out
