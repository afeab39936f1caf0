"""The thesis's own processing chain in front of the identification (thesis 003, Sections
3.2.2-3.3 and Appendix C).

The thesis did not fit its transfer functions to the quadcopter's motion but to what its
post-processing made of it: raw HX19 ranges (six receivers, two transmitters, uneven samples,
spikes) -> Filter 1 (velocity) -> Filter 2 (transmitter separation) -> CMD trilateration on
receivers 41, 42, 45 -> the stiff PV Kalman of Appendix C per axis (3 mm/s^2, 2 mm, after a
40-sample lead-in) and, for the heading, atan2 of the two CMD fixes -> PV Kalman (1 deg/s^2,
1 deg) -> linear interpolation onto the 0.05 s grid (``interp1``), input by nearest
neighbour. This module runs the same chain on the simulator's impulse flights
(:func:`sim.quadcopter.impulse_flight`), with the range model of :mod:`sim.ultrasonic` and
the pipeline :func:`estimator.ranging.localize` in its Appendix C configuration with the
literal thesis gates, so that :mod:`experiments.identification` can fit the same three
forms to truth-fed and chain-fed responses.

Outputs per axis (what the thesis fitted): thrust -> T20's (front transmitter's) filtered z,
pitch -> T20's filtered x (the simulated pitch moves along x; the thesis's along y), yaw rate
-> the filtered heading (unwrapped, rad). The hover level (median over the second before the
pulse) is subtracted; the fits estimate an offset anyway.

:func:`estimator.kalman.kalman_steady_state` (re-exported here) gives the closed form
against which the chain's filter lag is checked: the steady-state PV Kalman for per-sample
measurements has the poles of ``s^2 + 2 zeta w s + w^2`` with
``w = sqrt(sigma_process / sigma_measurement)`` and zeta = 1/sqrt(2) (independent of the
sample interval to first order), and it tracks a ramp with zero steady-state lag (the model
is exact for constant velocity); an acceleration a leaves an error of order a / w^2.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from estimator._checks import check_real
from estimator.orientation import unwrap_angle
from experiments.deferred import deferred_attributes
from sim.ultrasonic import UltrasonicNoiseModel, load_receivers, simulate_ranges

if TYPE_CHECKING:
    from estimator.kalman import kalman_steady_state  # re-exported: the closed form lives there
    from estimator.ranging import RangingConfig
    from estimator.sysid import TransferFit

#: imported where used, not here, so that --help and argument errors answer before
#: pandas / numba / scipy / matplotlib load; still importable from this module
__getattr__ = deferred_attributes(__name__, {
    "kalman_steady_state": ("estimator.kalman", "kalman_steady_state"),
    "RangeStreams": ("estimator.ranging", "RangeStreams"),
    "RangingConfig": ("estimator.ranging", "RangingConfig"),
    "localize": ("estimator.ranging", "localize"),
    "TransferFit": ("estimator.sysid", "TransferFit"),
    "fit_transfer_function": ("estimator.sysid", "fit_transfer_function"),
})

__all__ = ["CHAIN_AXES", "CHAIN_TRIPLE", "ChainFits", "ChainSpec", "chain_config",
           "chain_flights", "chain_response", "identify_chain", "kalman_steady_state",
           "noise_free"]

#: Appendix C: ``RCM_3 = [Rx41; Rx42; Rx45]``
CHAIN_TRIPLE = ("R41", "R42", "R45")
#: (transmitter index, coordinate index) of the fitted output; None = the heading
CHAIN_AXES = {"thrust": (0, 2), "pitch": (0, 0), "yaw_rate": None}
_FORMS = {"thrust": "two_poles", "pitch": "second_order", "yaw_rate": "one_pole"}


@dataclass(frozen=True)
class ChainSpec:
    """What the chain-fed experiment is made of (SI units).

    pre_s : hover before the pulse (the Appendix C lead-in of 40 samples, ~2.6 s, and the
        Kalman's settling, 1 / (zeta w) = 1.2 s, fit inside it; the thesis's impulse came
        86.7 s into its flight). before_s, record_s, grid_dt : the fitted record, starting
        ``before_s`` before the pulse, ``record_s`` long, on the thesis's 0.05 s grid (the
        truth-fed record is 1 s + 7 s as well). receivers : the layout file (Appendix C,
        centred). noise_model : the range fault model. gate_mode : "thesis" (the literal
        Filters 1/2) or "robust".
    """

    pre_s: float = 10.0
    before_s: float = 1.0
    record_s: float = 8.0
    grid_dt: float = 0.05
    receivers: str = "flight"
    noise_model: str = "ultrasonic"
    gate_mode: str = "thesis"

    def __post_init__(self) -> None:
        for name in ("pre_s", "before_s", "record_s", "grid_dt"):
            check_real(getattr(self, name), name, lo=0.0, lo_open=True)
        if self.before_s > self.pre_s:
            raise ValueError(f"before_s: must be <= pre_s ({self.pre_s}), got {self.before_s}")
        if self.gate_mode not in ("thesis", "robust"):
            raise ValueError(f"gate_mode: expected 'thesis' or 'robust', got "
                             f"{self.gate_mode!r}")


def noise_free(model: UltrasonicNoiseModel) -> UltrasonicNoiseModel:
    """The range model without noise, spikes, stale values or dropouts (same timing)."""
    return model.replace(sigma_m=0.0, max_error_m=0.0, spike_rate=0.0, hold_rate=0.0,
                         dropout_rate=0.0)


def chain_config(receiver_names: tuple[str, ...], spec: ChainSpec = ChainSpec(),
                 **changes) -> RangingConfig:
    """:meth:`RangingConfig.appendix_c` on the Appendix C triple with ``spec.gate_mode``;
    ``changes`` override fields (tests widen the Kalman with them)."""
    from estimator.ranging import RangingConfig

    idx = tuple(receiver_names.index(n) for n in CHAIN_TRIPLE)
    return RangingConfig.appendix_c(gate_mode=spec.gate_mode, receivers_used=idx, **changes)


def chain_flights(seed: int, spec: ChainSpec = ChainSpec()) -> dict:
    """One :func:`sim.quadcopter.impulse_flight` per axis, sample intervals from the range
    model's ``min/max_interval_s``, drawn from ``SeedSequence([seed, axis index, 50])``."""
    from sim.quadcopter import impulse_flight

    model = UltrasonicNoiseModel.load(spec.noise_model)
    out = {}
    for ai, axis in enumerate(CHAIN_AXES):
        g = np.random.default_rng(np.random.SeedSequence([seed, ai, 50]))
        out[axis] = impulse_flight(
            axis, g, pre_s=spec.pre_s,
            duration_s=spec.pre_s - spec.before_s + spec.record_s + 2 * spec.grid_dt,
            sample_interval_s=(model.min_interval_s, model.max_interval_s))
    return out


def _grid(flight, spec: ChainSpec) -> tuple[np.ndarray, np.ndarray]:
    """The fitted record's times (absolute, s) and the input on them (the pulse)."""
    n = math.floor(spec.record_s / spec.grid_dt + 1e-9) + 1
    tg = flight.pre_s - spec.before_s + np.arange(n) * spec.grid_dt
    on = (tg >= flight.pre_s - 1e-9) & (tg < flight.pre_s + flight.pulse_s - 1e-9)
    return tg, np.where(on, flight.amplitude, 0.0)


def _chain_signal(res, axis: str) -> np.ndarray:
    """The chain's output of ``axis`` at the epochs of a :class:`RangingResult`."""
    sel = CHAIN_AXES[axis]
    if sel is None:
        return unwrap_angle(res.heading)
    return res.kalman[:, sel[0], sel[1]]


def chain_response(flight, axis: str, model: UltrasonicNoiseModel, rng: np.random.Generator,
                   spec: ChainSpec = ChainSpec(), config: RangingConfig | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ranges of ``flight`` (fields ``t, sensor_positions, pre_s, pulse_s, amplitude``)
    through the chain; returns ``(t, u, y)`` on the fitted grid, ``t`` from 0, ``y`` minus
    its median over the ``before_s`` before the pulse."""
    from estimator.ranging import RangeStreams, localize

    names, rec = load_receivers(spec.receivers)
    config = config if config is not None else chain_config(names, spec)
    ranges = simulate_ranges(flight.t, flight.sensor_positions, rec, model, rng)
    res = localize(RangeStreams.from_synchronous(flight.t, ranges), rec, config, tight=False)
    sig = _chain_signal(res, axis)
    ok = np.isfinite(sig)
    tg, u = _grid(flight, spec)
    if tg[0] < res.epochs[ok][0] or tg[-1] > res.epochs[ok][-1]:
        raise ValueError(f"spec: the record {tg[0]:.3g}-{tg[-1]:.3g} s is not covered by the "
                         f"chain's output ({res.epochs[ok][0]:.3g}-{res.epochs[ok][-1]:.3g} "
                         "s); lengthen pre_s or the flight")
    y = np.interp(tg, res.epochs[ok], sig[ok])
    y -= np.median(y[tg < flight.pre_s - 1e-9])
    return tg - tg[0], u, y


@dataclass(frozen=True, eq=False)
class ChainFits:
    """Chain-fed fits of one axis: ``t, u`` the record, ``y_noise_free`` / ``y_noisy`` the
    chain's output from ranges without / with the range model's faults, ``noise_free`` /
    ``noisy`` their fits, ``mc`` fits of further range-noise realisations."""

    axis: str
    t: np.ndarray
    u: np.ndarray
    y_noise_free: np.ndarray
    y_noisy: np.ndarray
    noise_free: TransferFit
    noisy: TransferFit
    mc: tuple[TransferFit, ...]


def identify_chain(flights: Mapping, *, seed: int = 0, n_runs: int = 3, n_starts: int = 8,
                   rel_tol: float = 0.25, spec: ChainSpec = ChainSpec(),
                   config: RangingConfig | None = None) -> dict[str, ChainFits]:
    """Fit each axis of ``flights`` (``{axis: flight}``) through the chain: noise-free
    ranges, one realisation of the range model and ``n_runs`` further ones. Randomness:
    ``SeedSequence([seed, axis index, 100 + run])``: run 0 = the tabulated realisation,
    1..n_runs the Monte Carlo; the fits' starts use runs 90 (noise-free) and 91."""
    from estimator.sysid import fit_transfer_function

    model = UltrasonicNoiseModel.load(spec.noise_model)
    clean_model = noise_free(model)
    out = {}
    for ai, axis in enumerate(CHAIN_AXES):
        if axis not in flights:
            continue

        def rng(run: int, ai: int = ai) -> np.random.Generator:
            return np.random.default_rng(np.random.SeedSequence([seed, ai, 100 + run]))

        def response(m: UltrasonicNoiseModel, g: np.random.Generator, axis: str = axis):
            return chain_response(flights[axis], axis, m, g, spec, config)

        t, u, y0 = response(clean_model, rng(90))
        y1 = response(model, rng(0))[2]

        def fit(y: np.ndarray, g: np.random.Generator, t=t, u=u, axis: str = axis):
            return fit_transfer_function(t, u, y, _FORMS[axis], n_starts=n_starts, rng=g,
                                         rel_tol=rel_tol)

        mc = tuple(fit(response(model, rng(run))[2], rng(run))
                   for run in range(1, n_runs + 1))
        out[axis] = ChainFits(axis=axis, t=t, u=u, y_noise_free=y0, y_noisy=y1,
                              noise_free=fit(y0, rng(90)), noisy=fit(y1, rng(91)), mc=mc)
    return out
