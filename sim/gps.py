"""Stationary GPS sessions: a generative error model, and replay of stationary error onto motion.

The GPS dissertation (000_8f82f8df647bf685.txt) recorded eight receivers of one make on a
stationary platform for about 4000 s at 1 Hz (Section 4.1.1): sensor 4 never reported, a
power failure early on (data before it discarded), missing epochs, errors that are not
normal (Figs 4.7-4.8), strongly autocorrelated even after an AR(1) fit (Section 4.3,
Figs 4.9-4.15), with plateaus and transitions, each sensor with its own variance and trend
(Section 4.2), and pairwise distances that varied widely over time (Figs 4.4-4.6). Its moving
experiments took each sensor's deviation from its average stationary location and added it
to the simulated truth (Section 4.1.2). This module provides

- :class:`StationarySession`: a recording ``t (n,)``, ``obs (n, m, 2)`` in a local metric
  frame (x east, y north, metres, NaN = missing), receiver names, optional true antenna
  positions, metadata; saved to / loaded from one ``.npz`` file.
- :class:`GpsNoiseModel`: a generative model of such a recording, read from TOML
  (``models/noise/*.toml``; every parameter is documented there with unit and source).
- :func:`synthesize_session`: draw a session for a sensor configuration at a fixed pose.
- :func:`replay`: the dissertation's construction, truth + (observation - receiver mean).
- :func:`replay_one`: one receiver's session driving all m antennas, in one of the named
  modes of :data:`REPLAY_MODES` (what each implies for heading is stated there).
- :func:`observe`: a cell's observations from a model, a session or nothing.

Error model (per axis, per receiver i, sample k; all components independent)::

    e_i[k] = c[k] + s_i * r_i[k] + w_i[k] + b_i + p_i[k] + o_i[k]

    c    common-mode Gauss-Markov of order gm_order (1 = AR(1), 2 = smooth), std
         sigma_m * sqrt(common_fraction), pole time constant common_tau_s
    r_i  per-receiver Gauss-Markov, std sigma_m * sqrt(1 - common_fraction), tau receiver_tau_s
    s_i  per-receiver scale, lognormal: exp(N(0, receiver_sigma_spread^2)) (median 1)
    w_i  per-receiver white noise, N(0, white_sigma_m^2) (sample-to-sample jitter)
    b_i  per-receiver constant bias, N(0, bias_sigma_m^2)
    p_i  plateau level: redrawn N(0, step_sigma_m^2) at Poisson(step_rate_per_h) transitions,
         reached by a linear ramp of step_ramp_s seconds (stationary: its variance stays
         step_sigma_m^2)
    o_i  heavy-tailed outliers: with probability outlier_rate per sample, outlier_scale_m * t(df)

and then missing samples: two-state Markov dropouts (missing_fraction, mean_burst_s), dead
receivers (all NaN), and a power-failure interval in which no receiver reports.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from estimator._checks import check_int, check_real
from estimator.configuration import SensorConfig
from estimator.model_files import MODELS_DIR, read_model_toml
from sim.atomic import atomic_write
from sim.truth import Truth

__all__ = [
    "NOISE_DIR",
    "REPLAY_MODES",
    "SESSION_REPLAY_KEYS",
    "GpsModelError",
    "GpsNoiseModel",
    "StationarySession",
    "first_order_filter",
    "gauss_markov",
    "markov_dropouts",
    "observe",
    "receiver_errors",
    "replay",
    "replay_one",
    "synthesize_session",
]

NOISE_DIR = MODELS_DIR / "noise"


class GpsModelError(ValueError):
    """A GPS noise model (or its TOML file) is invalid; the message names the field."""


# --------------------------------------------------------------------------- session
@dataclass(frozen=True, eq=False)
class StationarySession:
    """A stationary multi-receiver GPS recording in a local metric frame.

    Attributes
    ----------
    t : (n,) float64, seconds, strictly increasing (usually 0, 1, 2, ... at 1 Hz).
    obs : (n, m, 2) float64, metres, x east / y north in a local frame; NaN = no report.
    names : tuple of m str, receiver names (match the sensor configuration's names).
    truth_positions : (m, 2) float64 or None, true antenna positions in the same frame
        (known for synthetic sessions; None for real recordings, as in the dissertation).
    meta : dict, JSON-serialisable. Keys used by this project: ``source`` ("synthetic",
        "nmea", "tumbleweed_csv"), ``receivers`` (per-receiver dicts), ``alignment``
        ("utc" = time-aligned on UTC, "independent" = separate series each starting at
        t = 0, "synthetic"), ``frame`` (CRS / origin description), ``skipped`` (counts per
        skip class), ``power_failure_s`` ([start, stop] or None).
    """

    t: np.ndarray
    obs: np.ndarray
    names: tuple[str, ...]
    truth_positions: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.shape[0] < 1:
            raise ValueError(f"t: expected shape (n,) with n >= 1, got {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError("t: contains non-finite times")
        if t.shape[0] > 1 and not np.all(np.diff(t) > 0):
            k = int(np.argmin(np.diff(t)))
            raise ValueError(f"t: must be strictly increasing; t[{k}]={t[k]!r}, "
                             f"t[{k+1}]={t[k+1]!r}")
        obs = np.asarray(self.obs, dtype=float)
        if obs.ndim != 3 or obs.shape[0] != t.shape[0] or obs.shape[2] != 2:
            raise ValueError(f"obs: expected shape ({t.shape[0]}, m, 2), got {obs.shape}")
        if np.any(np.isinf(obs)):
            raise ValueError("obs: contains infinite values (use NaN for missing)")
        names = tuple(str(s) for s in self.names)
        if len(names) != obs.shape[1]:
            raise ValueError(f"names: {len(names)} names for {obs.shape[1]} receivers")
        if len(set(names)) != len(names):
            raise ValueError(f"names: duplicate receiver names in {names!r}")
        tp = self.truth_positions
        if tp is not None:
            tp = np.asarray(tp, dtype=float)
            if tp.shape != (obs.shape[1], 2):
                raise ValueError(f"truth_positions: expected shape ({obs.shape[1]}, 2), got "
                                 f"{tp.shape}")
        half = np.isnan(obs).any(axis=2) & ~np.isnan(obs).all(axis=2)
        if half.any():
            k, j = np.argwhere(half)[0]
            raise ValueError(f"obs: sample {k} of receiver {names[j]!r} has one NaN coordinate; "
                             f"a missing fix must be NaN in both x and y")
        obs = obs.copy()
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "obs", obs)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "truth_positions", tp)
        object.__setattr__(self, "meta", dict(self.meta))

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    @property
    def m(self) -> int:
        """Number of receivers."""
        return int(self.obs.shape[1])

    @property
    def present(self) -> np.ndarray:
        """(n, m) bool, True where a receiver reported."""
        return ~np.isnan(self.obs[..., 0])

    @property
    def dead(self) -> tuple[str, ...]:
        """Receivers that never reported."""
        return tuple(n for n, p in zip(self.names, self.present.any(axis=0)) if not p)

    def receiver_means(self) -> np.ndarray:
        """(m, 2) mean observed position per receiver over the session (NaN for dead ones)."""
        _, mean = _centre(self.obs)
        return mean

    def errors(self) -> np.ndarray:
        """(n, m, 2) observation minus true position (needs ``truth_positions``)."""
        if self.truth_positions is None:
            raise ValueError("truth_positions: this session has no known truth (real recording)")
        return self.obs - self.truth_positions[None]

    def slice(self, start_s: float | None = None, stop_s: float | None = None) -> StationarySession:
        """Samples with ``start_s <= t < stop_s`` (seconds, either bound optional).

        Times are kept as recorded (not shifted to zero). ``meta["sliced_s"]`` records the
        bounds. Used to discard data before a power failure, as the dissertation did
        (Section 4.1).
        """
        keep = np.ones(self.n, dtype=bool)
        if start_s is not None:
            keep &= self.t >= start_s
        if stop_s is not None:
            keep &= self.t < stop_s
        if not keep.any():
            raise ValueError(f"slice: no samples in [{start_s!r}, {stop_s!r}) "
                             f"(t spans {self.t[0]!r}..{self.t[-1]!r})")
        meta = dict(self.meta)
        meta["sliced_s"] = [start_s, stop_s]
        return StationarySession(self.t[keep], self.obs[keep], self.names,
                                 self.truth_positions, meta)

    def after_power_failure(self) -> StationarySession:
        """The part after the recorded power failure (the dissertation's usable data).

        Returns ``self`` when ``meta["power_failure_s"]`` is absent or None.
        """
        pf = self.meta.get("power_failure_s")
        if not pf:
            return self
        return self.slice(start_s=float(pf[1]))

    def save(self, path: str | Path) -> Path:
        """Write to one ``.npz`` file (atomically: temp file then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {"t": self.t, "obs": self.obs, "names": np.array(self.names),
                  "meta": np.array(json.dumps(self.meta, sort_keys=True, default=_json_default))}
        if self.truth_positions is not None:
            arrays["truth_positions"] = self.truth_positions

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **arrays)

        return atomic_write(path, write)

    @classmethod
    def load(cls, path: str | Path) -> StationarySession:
        """Read a file written by :meth:`save`."""
        with np.load(Path(path), allow_pickle=False) as z:
            tp = z["truth_positions"] if "truth_positions" in z.files else None
            return cls(t=z["t"], obs=z["obs"], names=tuple(str(s) for s in z["names"]),
                       truth_positions=tp, meta=json.loads(str(z["meta"])))

    def __repr__(self) -> str:
        frac = 1.0 - self.present.mean()
        return (f"StationarySession(n={self.n}, m={self.m}, names={list(self.names)}, "
                f"missing={frac:.1%}, truth={'yes' if self.truth_positions is not None else 'no'}, "
                f"source={self.meta.get('source')!r})")


def _json_default(o: object) -> object:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _centre(obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-receiver deviation from the session mean, computed exactly for constant series.

    obs (n, m, 2) -> (dev (n, m, 2), mean (m, 2)). The mean is taken as
    ``x_ref + mean(x - x_ref)`` with ``x_ref`` the receiver's first valid sample, so a
    constant series has exactly zero deviation and UTM-sized coordinates lose no precision.
    Dead receivers get NaN means and all-NaN deviations.
    """
    m = obs.shape[1]
    present = ~np.isnan(obs[..., 0])
    first = np.argmax(present, axis=0)                      # (m,) first valid index (0 if none)
    ref = obs[first, np.arange(m)]                           # (m, 2)
    alive = present.any(axis=0)
    ref = np.where(alive[:, None], ref, 0.0)
    rel = obs - ref[None]
    count = present.sum(axis=0)                              # (m,)
    with np.errstate(invalid="ignore", divide="ignore"):
        mrel = np.where(alive[:, None], np.nansum(rel, axis=0) / np.maximum(count, 1)[:, None],
                        np.nan)
    dev = rel - mrel[None]
    return dev, ref + mrel


# --------------------------------------------------------------------------- noise model
_FIELD_DOCS = {
    "sigma_m": "per-axis std of the Gauss-Markov error (common + per-receiver), m",
    "common_fraction": "share of that variance common to all receivers, 0..1",
    "common_tau_s": "correlation time of the common-mode Gauss-Markov process, s",
    "receiver_tau_s": "correlation time of the per-receiver Gauss-Markov process, s",
    "receiver_sigma_spread": "log-std of the per-receiver scale on the per-receiver part, -",
    "gm_order": "order of both Gauss-Markov processes: 1 (AR(1)) or 2 (smooth), -",
    "white_sigma_m": "per-axis std of per-receiver white noise, m",
    "bias_sigma_m": "per-axis std of each receiver's constant bias, m",
    "step_rate_per_h": "plateau transitions per receiver per hour",
    "step_sigma_m": "per-axis std of plateau levels, m",
    "step_ramp_s": "duration of the linear ramp between plateaus, s",
    "outlier_rate": "probability per sample and receiver of an outlier",
    "outlier_scale_m": "scale of the Student-t outlier added per axis, m",
    "outlier_df": "degrees of freedom of the Student-t outlier",
    "missing_fraction": "stationary fraction of missing samples per receiver (bursty)",
    "mean_burst_s": "mean length of a dropout burst, s",
    "dead": "receiver names that never report (besides the configuration's dead)",
    "power_failure_start_s": "start of the interval with no reports at all, s",
    "power_failure_duration_s": "length of that interval, s (0 = none)",
}


@dataclass(frozen=True)
class GpsNoiseModel:
    """Generative model of a stationary multi-receiver GPS session (see module docstring).

    All fields are SI (metres, seconds); the TOML file uses the same flat names, and
    :meth:`with_overrides` takes them as keywords, so a sweep can set e.g.
    ``common_fraction`` by name. ``sigma_common_m`` / ``sigma_receiver_m`` are derived.
    """

    sigma_m: float = 2.0
    common_fraction: float = 0.5
    common_tau_s: float = 600.0
    receiver_tau_s: float = 120.0
    receiver_sigma_spread: float = 0.3
    gm_order: int = 2
    white_sigma_m: float = 0.03
    bias_sigma_m: float = 0.5
    step_rate_per_h: float = 4.0
    step_sigma_m: float = 0.5
    step_ramp_s: float = 20.0
    outlier_rate: float = 0.002
    outlier_scale_m: float = 2.0
    outlier_df: float = 3.0
    missing_fraction: float = 0.03
    mean_burst_s: float = 5.0
    dead: tuple[str, ...] = ()
    power_failure_start_s: float = 0.0
    power_failure_duration_s: float = 0.0
    name: str = "gps"
    description: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "dead", tuple(str(d) for d in self.dead))
        for f in dataclasses.fields(self):
            if f.name in ("dead", "name", "description", "gm_order"):
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(float(v)):
                raise GpsModelError(f"{f.name}: must be a finite number, got {v!r}")
            object.__setattr__(self, f.name, float(v))
        nonneg = ("sigma_m", "receiver_sigma_spread", "white_sigma_m", "bias_sigma_m",
                  "step_rate_per_h",
                  "step_sigma_m", "step_ramp_s", "outlier_rate", "outlier_scale_m",
                  "missing_fraction", "power_failure_start_s", "power_failure_duration_s")
        for k in nonneg:
            if getattr(self, k) < 0:
                raise GpsModelError(f"{k}: must be >= 0, got {getattr(self, k)!r}")
        for k in ("common_tau_s", "receiver_tau_s", "outlier_df", "mean_burst_s"):
            if getattr(self, k) <= 0:
                raise GpsModelError(f"{k}: must be > 0, got {getattr(self, k)!r}")
        if not 0.0 <= self.common_fraction <= 1.0:
            raise GpsModelError(f"common_fraction: must be in [0, 1], got {self.common_fraction!r}")
        if not 0.0 <= self.outlier_rate <= 1.0:
            raise GpsModelError(f"outlier_rate: must be in [0, 1], got {self.outlier_rate!r}")
        if not 0.0 <= self.missing_fraction < 1.0:
            raise GpsModelError("missing_fraction: must be in [0, 1), got "
                                f"{self.missing_fraction!r}")
        if isinstance(self.gm_order, bool) or self.gm_order not in (1, 2):
            raise GpsModelError(f"gm_order: must be 1 or 2, got {self.gm_order!r}")
        object.__setattr__(self, "gm_order", int(self.gm_order))
        if len(set(self.dead)) != len(self.dead):
            raise GpsModelError(f"dead: duplicate names in {list(self.dead)!r}")

    # derived split of the Gauss-Markov variance
    @property
    def sigma_common_m(self) -> float:
        """Per-axis std of the common-mode component, m: sigma_m * sqrt(common_fraction)."""
        return self.sigma_m * math.sqrt(self.common_fraction)

    @property
    def sigma_receiver_m(self) -> float:
        """Per-axis std of the per-receiver component (before the receiver scale), m."""
        return self.sigma_m * math.sqrt(1.0 - self.common_fraction)

    def with_overrides(self, **kw: object) -> GpsNoiseModel:
        """A copy with fields replaced by name (validated); unknown names raise GpsModelError."""
        allowed = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(kw) - allowed)
        if unknown:
            raise GpsModelError(f"with_overrides: unknown field(s) {unknown}; allowed: "
                                f"{sorted(allowed)}")
        return dataclasses.replace(self, **kw)  # type: ignore[arg-type]

    def to_dict(self) -> dict:
        """Plain dict of all fields (JSON/TOML friendly)."""
        d = dataclasses.asdict(self)
        d["dead"] = list(self.dead)
        return d

    @classmethod
    def from_dict(cls, data: dict, *, source: str = "<dict>") -> GpsNoiseModel:
        """Build from the flat TOML key/value structure; unknown keys are rejected."""
        allowed = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - allowed)
        if unknown:
            raise GpsModelError(f"{source}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
        kw = dict(data)
        if "dead" in kw:
            if (not isinstance(kw["dead"], list)
                    or not all(isinstance(x, (str, int)) for x in kw["dead"])):
                raise GpsModelError(f"{source}: dead must be a list of receiver names, got "
                                    f"{kw['dead']!r}")
            kw["dead"] = tuple(str(x) for x in kw["dead"])
        for key in ("name", "description"):
            if key in kw and not isinstance(kw[key], str):
                raise GpsModelError(f"{source}: {key} must be a string, got {kw[key]!r}")
        try:
            return cls(**kw)
        except GpsModelError as exc:
            raise GpsModelError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, name_or_path: str | Path = "gps_stationary") -> GpsNoiseModel:
        """Load a TOML model: a path, or a name looked up in ``models/noise/``."""
        data, path = read_model_toml(name_or_path, NOISE_DIR, "noise model",
                                     error=GpsModelError, known_glob="gps*.toml")
        data.setdefault("name", path.stem)
        return cls.from_dict(data, source=str(path))


# --------------------------------------------------------------------------- generators
def gauss_markov(n: int, shape: tuple[int, ...], sigma: float | np.ndarray, tau_s: float,
                 dt_s: float, rng: np.random.Generator, order: int = 1) -> np.ndarray:
    """Stationary Gauss-Markov sequences of order 1 or 2, shape (n, *shape), std ``sigma``.

    Order 1 (AR(1)): x[k] = phi x[k-1] + sigma sqrt(1 - phi^2) w[k], phi = exp(-dt/tau),
    x[0] ~ N(0, sigma^2): the discrete form of dx = -x/tau dt + sigma sqrt(2/tau) dW, the
    dissertation's Eq. 2.2 AR(1) with delta = 0. ACF rho(k) = phi^k.
    Order 2 (critically damped, two equal poles at phi): the order-1 sequence filtered once
    more by g / (1 - phi B), g = (1 - phi^2) / sqrt(1 + phi^2) so the variance stays sigma^2;
    ACF rho(k) = phi^k (1 + k (1 - phi^2) / (1 + phi^2)); smooth (differentiable) paths, so
    an AR(1) fit leaves autocorrelated residuals. Started stationary by a burn-in of
    ceil(12 tau / dt) samples (phi^burn = e^-12).
    ``sigma`` broadcasts against ``shape``. The recursions run over time with every series
    side by side (:func:`first_order_filter`).
    """
    if n < 1:
        raise ValueError(f"n: must be >= 1, got {n!r}")
    if not tau_s > 0 or not dt_s > 0:
        raise ValueError(f"tau_s and dt_s: must be > 0, got tau_s={tau_s!r}, dt_s={dt_s!r}")
    if order not in (1, 2):
        raise ValueError(f"order: must be 1 or 2, got {order!r}")
    phi = math.exp(-dt_s / tau_s)
    burn = 0 if order == 1 else math.ceil(12.0 * tau_s / dt_s)
    w = rng.standard_normal((n + burn, *shape))
    w[1:] *= math.sqrt(max(1.0 - phi * phi, 0.0))
    x = first_order_filter(w, 1.0, phi)
    if order == 2:
        g = (1.0 - phi * phi) / math.sqrt(1.0 + phi * phi)
        x = first_order_filter(x, g, phi)[burn:]
    return x * np.asarray(sigma, dtype=float)


def first_order_filter(x: np.ndarray, gain: float, phi: float, *,
                       engine: str = "numba") -> np.ndarray:
    """``y[0] = gain x[0]``, ``y[k] = gain x[k] + phi y[k-1]`` along axis 0 of x (n, ...).

    The same numbers, bit for bit, as ``scipy.signal.lfilter([gain], [1, -phi], x, axis=0)``
    (its direct form computes ``gain x[k] + (0 x[k-1] - (-phi) y[k-1])``, the same rounded
    operations; tests/test_gps.py checks it), without importing ``scipy.signal``, which
    costs each sweep worker ~0.6 s (it pulls in ``scipy.stats``). engine : "numba" (the
    compiled loop :func:`sim.kernels.ar1_filter`, ~0.1 ms for 3700 samples of 16 series) or
    "numpy" (the reference: two ufunc calls per sample, ~10 ms); the same numbers.
    """
    if engine not in ("numba", "numpy"):
        raise ValueError(f"engine: must be 'numba' or 'numpy', got {engine!r}")
    x = np.asarray(x, dtype=float)
    if x.shape[0] == 0:
        return x * gain
    flat = x.reshape(x.shape[0], -1)
    gx = flat * gain if gain != 1.0 else flat
    y = np.empty_like(flat)
    if engine == "numba":
        from sim.kernels import ar1_filter

        ar1_filter(np.ascontiguousarray(gx), float(phi), y)
        return y.reshape(x.shape)
    y[0] = gx[0]
    tmp = np.empty(flat.shape[1])
    mul, add = np.multiply, np.add
    prev = y[0]
    for k in range(1, flat.shape[0]):
        mul(prev, phi, out=tmp)
        prev = y[k]
        add(gx[k], tmp, out=prev)
    return y.reshape(x.shape)


def markov_dropouts(n: int, m: int, missing_fraction: float, mean_burst: float,
                    rng: np.random.Generator) -> np.ndarray:
    """(n, m) bool, True = missing: a stationary two-state Markov chain per receiver.

    Missing bursts have geometric lengths with mean ``mean_burst`` samples (>= 1); the
    reporting runs have mean ``mean_burst * (1 - f) / f`` so that the stationary missing
    fraction is ``f = missing_fraction``. The chain starts in its stationary distribution
    (memorylessness makes the first run length geometric too). Built run by run with
    vectorized draws, not sample by sample.
    """
    out = np.zeros((n, m), dtype=bool)
    f = float(missing_fraction)
    if f <= 0.0 or n == 0:
        return out
    mean_burst = max(float(mean_burst), 1.0)
    q = 1.0 / mean_burst                 # P(missing -> present) per sample
    p = q * f / (1.0 - f)                # P(present -> missing) per sample
    if p >= 1.0:
        raise ValueError(f"missing_fraction={f!r} with mean_burst={mean_burst!r} samples needs "
                         f"P(present->missing)={p:.3g} > 1; shorten the bursts or lower the "
                         "fraction")
    # enough runs to cover n samples with margin (each pair of runs averages 1/p + 1/q)
    pairs = int(n / (1.0 / p + 1.0 / q) * 1.5) + 20
    for j in range(m):
        start_missing = rng.random() < f
        while True:
            on = rng.geometric(p, size=pairs)     # present runs
            off = rng.geometric(q, size=pairs)    # missing runs
            runs = np.empty(2 * pairs, dtype=np.int64)
            if start_missing:
                runs[0::2], runs[1::2] = off, on
            else:
                runs[0::2], runs[1::2] = on, off
            if runs.sum() >= n:
                break
            pairs *= 2
        state = np.zeros(2 * pairs, dtype=bool)
        state[(0 if start_missing else 1)::2] = True
        out[:, j] = np.repeat(state, runs)[:n]
    return out


def _plateaus(n: int, m: int, dt: float, rate_per_h: float, sigma: float, ramp_s: float,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Plateau component (n, m, 2) and the transition counts (m,).

    Each receiver starts on a level N(0, sigma^2) per axis; transitions arrive as a Poisson
    process (rate per hour); at each one a new level is drawn and reached by a linear ramp
    of ``ramp_s`` seconds. Levels are redrawn, not accumulated, so the process is stationary.
    """
    out = np.zeros((n, m, 2))
    counts = np.zeros(m, dtype=np.int64)
    if sigma <= 0.0:
        return out, counts
    t = np.arange(n) * dt
    duration = n * dt
    for j in range(m):
        k = rng.poisson(rate_per_h * duration / 3600.0) if rate_per_h > 0 else 0
        times = np.sort(rng.uniform(0.0, duration, size=k))
        levels = rng.normal(0.0, sigma, size=(k + 1, 2))
        counts[j] = k
        level = np.broadcast_to(levels[0], (n, 2)).copy()
        for i, ts in enumerate(times):
            # ramp from the current level toward the new one (piecewise linear, vectorized)
            frac = np.clip((t - ts) / ramp_s, 0.0, 1.0) if ramp_s > 0 else (t >= ts).astype(float)
            level += frac[:, None] * (levels[i + 1] - levels[i])[None, :]
        out[:, j] = level
    return out, counts


def receiver_errors(model: GpsNoiseModel, m: int, n: int, dt_s: float,
                    rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """Error sequences (n, m, 2) in metres, before missingness, and the drawn parameters.

    Returns ``(errors, drawn)`` with ``drawn`` holding the per-receiver scales, biases and
    plateau transition counts and the outlier count (for reports and tests).
    """
    common = gauss_markov(n, (1, 2), model.sigma_common_m, model.common_tau_s, dt_s, rng,
                          order=model.gm_order)
    scale = np.exp(rng.normal(0.0, model.receiver_sigma_spread, size=m)) \
        if model.receiver_sigma_spread > 0 else np.ones(m)
    indep = gauss_markov(n, (m, 2), model.sigma_receiver_m * scale[:, None], model.receiver_tau_s,
                         dt_s, rng, order=model.gm_order)
    white = rng.normal(0.0, model.white_sigma_m, size=(n, m, 2)) if model.white_sigma_m > 0 else 0.0
    bias = (rng.normal(0.0, model.bias_sigma_m, size=(m, 2)) if model.bias_sigma_m > 0
            else np.zeros((m, 2)))
    plateau, steps = _plateaus(n, m, dt_s, model.step_rate_per_h, model.step_sigma_m,
                               model.step_ramp_s, rng)
    out = np.zeros((n, m, 2))
    n_out = 0
    if model.outlier_rate > 0 and model.outlier_scale_m > 0:
        hit = rng.random((n, m)) < model.outlier_rate
        n_out = int(hit.sum())
        out[hit] = model.outlier_scale_m * rng.standard_t(model.outlier_df, size=(n_out, 2))
    err = common + indep + white + bias[None] + plateau + out
    drawn = {"receiver_scale": scale.tolist(), "bias_m": bias.tolist(),
             "plateau_transitions": steps.tolist(), "outliers": n_out}
    return err, drawn


#: Largest session :func:`synthesize_session` draws, in receiver-samples (n * m): 8 receivers
#: for 46 days at 1 Hz or 7 days at 6.6 Hz; each (n, m, 2) float64 array is then 0.5 GB.
#: Larger requests are typos (e.g. a length in ms), refused before any allocation.
MAX_SESSION_VALUES = 3.2e7


def synthesize_session(model: GpsNoiseModel, config: SensorConfig, duration_s: float,
                       rng: np.random.Generator, rate_hz: float = 1.0, *,
                       position: Sequence[float] = (0.0, 0.0), yaw: float = 0.0
                       ) -> StationarySession:
    """Draw a stationary session for ``config`` at a fixed pose.

    The true antenna positions are the configuration's body positions (xy) rotated by
    ``yaw`` (radians, CCW from +x) and shifted by ``position`` (metres); observations are
    truth + :func:`receiver_errors`, then dropouts, dead receivers (the model's ``dead``
    plus the configuration's ``dead``) and the power failure are applied as NaN.
    Shapes: t (n,), obs (n, m, 2) with n = round(duration_s * rate_hz).
    """
    if not (isinstance(duration_s, numbers.Real) and duration_s > 0 and math.isfinite(duration_s)):
        raise ValueError(f"duration_s: must be a positive number, got {duration_s!r}")
    if not (isinstance(rate_hz, numbers.Real) and rate_hz > 0 and math.isfinite(rate_hz)):
        raise ValueError(f"rate_hz: must be a positive number, got {rate_hz!r}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(  # noqa: TRY004 (project contract: bad input is ValueError)
            f"rng: must be a numpy.random.Generator, got {type(rng).__name__}")
    for d in model.dead:
        if d not in config.names:
            raise ValueError(f"dead: receiver {d!r} of noise model {model.name!r} is not in "
                             f"configuration {config.name!r} (names {list(config.names)})")
    n = round(float(duration_s) * float(rate_hz))
    if n < 1:
        raise ValueError(f"duration_s * rate_hz: gives {n} samples; need at least 1")
    if n * config.m > MAX_SESSION_VALUES:
        raise ValueError(f"duration_s * rate_hz: {duration_s!r} s at {rate_hz!r} Hz is {n} samples "
                         f"x {config.m} receivers, more than {MAX_SESSION_VALUES:.0e} "
                         "receiver-samples (about 0.5 GB per array); synthesize a shorter session")
    dt = 1.0 / rate_hz
    m = config.m
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s], [s, c]])
    truth = config.body_positions[:, :2] @ R.T + np.asarray(position, dtype=float)[None, :2]

    err, drawn = receiver_errors(model, m, n, dt, rng)
    missing = markov_dropouts(n, m, model.missing_fraction, model.mean_burst_s * rate_hz, rng)
    t = np.arange(n) * dt
    pf = None
    if model.power_failure_duration_s > 0:
        lo = model.power_failure_start_s
        hi = model.power_failure_start_s + model.power_failure_duration_s
        missing |= ((t >= lo) & (t < hi))[:, None]
        pf = [lo, hi]
    dead = set(model.dead) | set(config.dead)
    for j, name in enumerate(config.names):
        if name in dead:
            missing[:, j] = True
    obs = truth[None] + err
    obs[missing] = np.nan
    meta = {
        "source": "synthetic",
        "alignment": "synthetic",
        "frame": "local metric frame, x east / y north, metres (synthetic)",
        "model": model.to_dict(),
        "config": config.name,
        "pose": {"position_m": [float(v) for v in np.asarray(position, dtype=float)[:2]],
                 "yaw_rad": float(yaw)},
        "rate_hz": float(rate_hz),
        "duration_s": float(duration_s),
        "power_failure_s": pf,
        "dead": sorted(dead, key=config.names.index),
        "drawn": drawn,
        "receivers": [{"name": nme} for nme in config.names],
        "skipped": {},
    }
    return StationarySession(t=t, obs=obs, names=config.names, truth_positions=truth, meta=meta)


# --------------------------------------------------------------------------- replay
def _check_rate(truth: Truth, session: StationarySession) -> None:
    """ValueError if the median sample intervals of truth and session differ by > 1 %
    (replay aligns by sample: a different rate would stretch time)."""
    if truth.n > 1 and session.n > 1:
        dt_truth = float(np.median(np.diff(truth.t)))
        dt_sess = float(np.median(np.diff(session.t)))
        if abs(dt_truth - dt_sess) > 0.01 * dt_sess:
            raise ValueError(f"session: sample interval {dt_sess:.6g} s differs from the truth's "
                             f"{dt_truth:.6g} s; replay aligns by sample (pass "
                             f"check_rate=False to accept)")


ReplayMode = Literal["error", "wrap", "random_offset"]


def replay(truth: Truth, session: StationarySession, *, rng: np.random.Generator | None = None,
           mode: ReplayMode = "error", start: int | None = None, match: str = "auto",
           check_rate: bool = True) -> np.ndarray:
    """Observed antenna positions for a moving truth, from a stationary session (Section 4.1.2).

    ``obs[k, j] = truth.sensor_positions[k, j, :2] + (session.obs[s_k, i_j] - mean_i)``
    where ``mean_i`` is receiver ``i_j``'s mean over the whole session (so its replayed error
    is zero-mean over the session, exactly the dissertation's "errors from the average
    location of each sensor"), and ``s_k`` the session sample used at truth sample ``k``:
    time-aligned by sample, no resampling. Missing session samples stay NaN; a dead receiver
    stays dead.

    Parameters
    ----------
    truth : Truth with sensor_positions (n, m, 3), metres.
    session : StationarySession with at least m receivers.
    rng : Generator, needed for ``mode="random_offset"`` when ``start`` is None.
    mode : what to do about the session's length:
        ``"error"`` (default): use samples ``start .. start+n-1``; ValueError if the session
        is too short. ``"wrap"``: indices ``(start + k) mod n_session`` (the seam is a jump
        in the error). ``"random_offset"``: ``start`` drawn uniformly from the Generator
        (0 .. n_session-1) when not given, then wrap.
    start : first session sample (default 0, or random for ``random_offset``).
    match : ``"auto"`` (by name when every truth sensor name is a session receiver; by order
        when no names are shared; ValueError naming the missing names when only some are),
        ``"name"`` or ``"order"`` (truth sensor j gets session receiver j).
    check_rate : raise ValueError if the session's and the truth's median sample intervals
        differ by more than 1 % (sample alignment would then stretch time).

    Returns
    -------
    obs : (n, m, 2) float64, metres, NaN = missing.
    """
    if mode not in ("error", "wrap", "random_offset"):
        raise ValueError(f"mode: must be 'error', 'wrap' or 'random_offset', got {mode!r}")
    n, m = truth.n, truth.m
    ns = session.n
    # receiver matching
    if match not in ("auto", "name", "order"):
        raise ValueError(f"match: must be 'auto', 'name' or 'order', got {match!r}")
    shared = [nm for nm in truth.sensor_names if nm in session.names]
    if match == "name" or (match == "auto" and shared):
        missing_names = [nm for nm in truth.sensor_names if nm not in session.names]
        if missing_names:
            raise ValueError(f"session: has no receiver named {missing_names!r} "
                             f"(session names {list(session.names)}, truth names "
                             f"{list(truth.sensor_names)})")
        idx = np.array([session.names.index(nm) for nm in truth.sensor_names], dtype=np.int64)
    else:
        if session.m < m:
            raise ValueError(f"session: {session.m} receivers for {m} truth sensors (matching by "
                             "order)")
        idx = np.arange(m, dtype=np.int64)
    if check_rate:
        _check_rate(truth, session)
    # session sample per truth sample
    if start is None:
        if mode == "random_offset":
            if not isinstance(rng, np.random.Generator):
                raise ValueError("rng: mode='random_offset' needs a numpy.random.Generator")
            start = int(rng.integers(0, ns))
        else:
            start = 0
    if (isinstance(start, bool) or not isinstance(start, (int, np.integer))
            or not 0 <= int(start) < ns):
        raise ValueError(f"start: must be an integer sample index in 0..{ns - 1}, got {start!r}")
    start = int(start)
    if mode == "error":
        if start + n > ns:
            raise ValueError(f"session: {ns} samples from start={start} cannot cover the truth's "
                             f"{n} samples (mode='error'; use mode='wrap' or 'random_offset')")
        rows = np.arange(start, start + n)
    else:
        rows = (start + np.arange(n)) % ns
    dev, _ = _centre(session.obs[:, idx])                     # (ns, m, 2), zero-mean per receiver
    return truth.sensor_positions[:, :, :2] + dev[rows]


#: How a stationary session drives the m antennas of a truth, and what it implies for the
#: heading (whose error comes only from the part of the antennas' errors they do NOT share:
#: a shift common to every antenna moves the fitted pose without rotating it).
REPLAY_MODES = {
    "by_receiver": "one session receiver per antenna (by name or order, :func:`replay`): "
                   "the receivers' own common-mode and independent parts; heading as "
                   "observable as it was for those receivers recorded together",
    "identical": "every antenna gets the same receiver's error at the same time (what "
                 "duplicating one log gives): a pure translation, so the fitted heading is "
                 "exact and the CG error is the log's error; an optimistic bound for heading",
    "shifted": "antenna j gets the receiver's error at circular lag j * L samples (default "
               "L = n_session // m, the largest equal spacing): no common-mode part, so "
               "heading as poor as for independent receivers of this quality, a pessimistic "
               "bound (co-located receivers share part of their error). Independent only if "
               "the session is many correlation times long: the replayed error is zero-mean "
               "over the session, so m phases of a session a few correlation times long are "
               "anti-correlated and their mean (the CG error) is too small; the measured "
               "mean pair correlation is reported (info['pair_correlation'])",
    "common_plus_model": "the receiver's error moves every antenna together (real CG error, "
                         "invisible to the heading) plus, per antenna, the per-receiver part "
                         "of a noise model (its Gauss-Markov part sigma_m sqrt(1 - "
                         "common_fraction), biases, plateaus, outliers, dropouts): heading "
                         "error comes from the model alone",
}
def _mean_pair_correlation(err: np.ndarray) -> float:
    """Mean over antenna pairs and both axes of the sample correlation of the errors
    (n, m, 2) over time (pairwise complete samples; NaN if no pair has variance)."""
    m = err.shape[1]
    out = []
    for i in range(m):
        for j in range(i + 1, m):
            for k in range(2):
                a, b = err[:, i, k], err[:, j, k]
                ok = ~np.isnan(a) & ~np.isnan(b)
                if ok.sum() > 2 and np.std(a[ok]) > 0 and np.std(b[ok]) > 0:
                    out.append(float(np.corrcoef(a[ok], b[ok])[0, 1]))
    return float(np.mean(out)) if out else math.nan


#: Keys of ``noise_overrides`` that :func:`observe` accepts with a session.
SESSION_REPLAY_KEYS = ("replay", "receiver", "shift_s", "model")


def replay_one(truth: Truth, session: StationarySession, *, mode: str,
               rng: np.random.Generator, receiver: str | None = None,
               shift_s: float | None = None, model: str | Path | GpsNoiseModel | None = None,
               config: SensorConfig | None = None, start: int | None = None,
               check_rate: bool = True) -> tuple[np.ndarray, dict]:
    """Observations of all m antennas of ``truth`` from ONE receiver of ``session``.

    Each antenna gets that receiver's deviation from its session mean (the dissertation's
    error, Section 4.1.2) added to its true position, arranged by ``mode`` (one of
    :data:`REPLAY_MODES` except "by_receiver", which is :func:`replay`):

    - ``"identical"``: rows ``start .. start + n - 1`` for every antenna.
    - ``"shifted"``: antenna j reads rows ``(start + j L + k) mod n_session``, L =
      ``round(shift_s / dt)`` or ``n_session // m``; needs ``n_session >= n`` (no antenna
      repeats its own samples) and ``(m - 1) L < n_session`` (distinct lags). An antenna
      whose rows pass the session's end has a seam there (a jump, as ``replay(mode="wrap")``);
      ``info["seams"]`` counts them.
    - ``"common_plus_model"``: rows ``start .. start + n - 1`` for every antenna plus, per
      antenna, :func:`receiver_errors` of ``model`` with the common part removed
      (``sigma_m -> sigma_receiver_m``, ``common_fraction -> 0``) and its dropouts
      (:func:`markov_dropouts`) and dead receivers.

    truth : Truth, sensor positions (n, m, 3) metres at the session's sample interval
        (``check_rate``: within 1 %). session : StationarySession. receiver : the name of
        the session receiver to use (required when the session has more than one).
    rng : Generator: the start (when ``start`` is None, uniform over the admissible
        starts) and the model's draws. config : if given, its dead antennas stay NaN.
    Missing session samples are missing for every antenna that reads them.
    Returns ``(obs (n, m, 2) float64 metres, NaN = missing; info dict)`` with the mode,
    receiver, start, lag (samples, s), seams and ``pair_correlation``: the sample
    correlation of the replayed errors of every antenna pair over the run, averaged over
    pairs and axes (1 for "identical"; near 0 when "shifted" decorrelates, negative when
    the session is too short for m independent segments, see :data:`REPLAY_MODES`).
    """
    if mode not in REPLAY_MODES or mode == "by_receiver":
        raise ValueError(f"mode: must be one of {[k for k in REPLAY_MODES if k != 'by_receiver']} "
                         f"(by_receiver is sim.gps.replay), got {mode!r}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: must be a numpy.random.Generator, got {type(rng).__name__}")
    if not isinstance(truth, Truth) or not isinstance(session, StationarySession):
        raise TypeError("truth, session: expected a sim.truth.Truth and a StationarySession, "
                        f"got {type(truth).__name__} and {type(session).__name__}")
    n, m, ns = truth.n, truth.m, session.n
    if shift_s is not None and mode != "shifted":
        raise ValueError(f"shift_s: applies to mode 'shifted' only (mode {mode!r})")
    if model is not None and mode != "common_plus_model":
        raise ValueError(f"model: applies to mode 'common_plus_model' only (mode {mode!r})")
    if receiver is None:
        if session.m != 1:
            raise ValueError(f"receiver: the session has {session.m} receivers "
                             f"{list(session.names)}; name the one to replay")
        r = 0
    else:
        if str(receiver) not in session.names:
            raise ValueError(f"receiver: {receiver!r} is not in the session "
                             f"(receivers {list(session.names)})")
        r = session.names.index(str(receiver))
    if check_rate:
        _check_rate(truth, session)
    dt = float(np.median(np.diff(session.t))) if ns > 1 else 1.0
    if ns < n:
        raise ValueError(f"session: {ns} samples of receiver {session.names[r]!r} cannot cover "
                         f"the truth's {n} samples (mode {mode!r})")
    dev = _centre(session.obs[:, [r]])[0][:, 0]            # (ns, 2), zero-mean
    info: dict = {"mode": mode, "receiver": session.names[r], "n_session": ns}
    if start is not None:
        start = int(check_int(start, "start", 0, ns - 1 if mode == "shifted" else ns - n))
    if mode == "shifted":
        if m < 2:
            raise ValueError("mode 'shifted': needs at least 2 antennas")
        if shift_s is None:
            lag = ns // m
        else:
            lag = round(check_real(shift_s, "shift_s", lo=0.0, lo_open=True) / dt)
        if lag < 1 or (m - 1) * lag >= ns:
            raise ValueError(f"shift_s: a lag of {lag} samples for {m} antennas needs "
                             f"1 <= lag and (m - 1) * lag < {ns} session samples")
        if start is None:
            start = int(rng.integers(0, ns))
        first = start + lag * np.arange(m)
        rows = (first[None, :] + np.arange(n)[:, None]) % ns        # (n, m)
        err = dev[rows]                                              # (n, m, 2)
        info.update({"lag_samples": int(lag), "lag_s": lag * dt,
                     "seams": int(((first % ns) + n > ns).sum())})
    else:
        if start is None:
            start = int(rng.integers(0, ns - n + 1))
        common = dev[start:start + n]                                # (n, 2)
        err = np.repeat(common[:, None, :], m, axis=1)
        info.update({"lag_samples": 0, "lag_s": 0.0, "seams": 0})
        if mode == "common_plus_model":
            if model is None:
                raise ValueError("model: mode 'common_plus_model' needs a noise model "
                                 "(a GpsNoiseModel or a name in models/noise/)")
            mdl = model if isinstance(model, GpsNoiseModel) else GpsNoiseModel.load(model)
            per_model = mdl.with_overrides(sigma_m=mdl.sigma_receiver_m, common_fraction=0.0)
            per, drawn = receiver_errors(per_model, m, n, dt, rng)
            missing = markov_dropouts(n, m, mdl.missing_fraction, mdl.mean_burst_s / dt, rng)
            names = truth.sensor_names
            for d in mdl.dead:
                if d in names:
                    missing[:, names.index(d)] = True
            err = err + per
            err[missing] = np.nan
            info.update({"model": mdl.name, "drawn": drawn})
    info["start"] = int(start)
    info["pair_correlation"] = _mean_pair_correlation(err)
    obs = truth.sensor_positions[:, :, :2] + err
    if config is not None:
        obs[:, ~config.alive_mask] = np.nan
    return obs, info


# --------------------------------------------------------------------------- observe
def observe(truth: Truth, config: SensorConfig,
            noise: str | Path | GpsNoiseModel | StationarySession | None, *,
            rng: np.random.Generator | None = None, session_s: float = 4000.0,
            noise_overrides: dict | None = None) -> np.ndarray:
    """A cell's noisy GPS observations of a simulated truth: the one way the sweep, the
    tuning script and the tests build them (dissertation Sections 4.1.1-4.1.2).

    truth : Truth with sensor_positions (n, m, 3), metres, at the GPS rate.
    config : the SensorConfig the truth was simulated with (dead sensors stay NaN).
    noise : None or "none" (noise-free: the true antenna positions, dead ones NaN); a
        :class:`GpsNoiseModel` or a noise-model name/file (``models/noise/``); or a
        :class:`StationarySession` (a saved or imported recording).
    rng : the noise stream (required unless noise-free).
    session_s : length of the synthesized stationary session, s (the dissertation's
        recording lasted ~4000 s, Section 4.1.1); at least the run's length is used.
    noise_overrides : with a model, model fields replaced before synthesis (e.g.
        ``common_fraction``). With a session, how it drives the antennas
        (:data:`SESSION_REPLAY_KEYS`): ``replay`` = a mode of :data:`REPLAY_MODES`
        (default "by_receiver"), ``receiver`` (which one, for the one-receiver modes),
        ``shift_s`` ("shifted"), ``model`` (a noise-model name, "common_plus_model", whose
        fields may be overridden by the remaining keys).

    A model synthesizes a session of ``session_s`` seconds (plus the power failure), cut
    after its power failure as the dissertation did; a session is cut the same way. The
    run replays a random stretch of it (start drawn from ``rng``): truth + (observation -
    that receiver's mean over the whole session), :func:`replay` with ``mode="error"``, or
    :func:`replay_one` for the one-receiver modes.
    Returns obs (n, m, 2) float64 metres, NaN = missing, read-only.
    """
    if noise is None or (isinstance(noise, str) and noise == "none"):
        obs = truth.sensor_positions[:, :, :2].copy()
        obs[:, ~config.alive_mask] = np.nan
        obs.setflags(write=False)
        return obs
    if not isinstance(rng, np.random.Generator):
        # ValueError, not TypeError: the project's one error type for bad arguments
        raise ValueError(f"rng: noisy observations need a numpy.random.Generator, got {rng!r}")  # noqa: TRY004
    if isinstance(noise, StationarySession):
        session = noise.after_power_failure()
        opts = dict(noise_overrides or {})
        mode = opts.pop("replay", "by_receiver")
        if mode not in REPLAY_MODES:
            raise ValueError(f"noise_overrides.replay: unknown mode {mode!r}; choose one of "
                             f"{list(REPLAY_MODES)}")
        if mode == "by_receiver":
            if opts:
                raise ValueError(f"noise_overrides: {sorted(opts)} do not apply to a session "
                                 f"replayed by receiver (keys {list(SESSION_REPLAY_KEYS)})")
            if session.m < truth.m:
                raise ValueError(
                    f"noise: the session has {session.m} receiver(s) for {truth.m} antennas; "
                    f"drive them from one receiver with noise_overrides={{'replay': MODE}}, "
                    f"MODE one of 'shifted' (decorrelated segments), 'common_plus_model' "
                    f"(+ a model's per-receiver part) or 'identical' (common-mode only); "
                    f"see sim.gps.REPLAY_MODES")
        else:
            receiver, shift_s, mdl = (opts.pop(k, None) for k in ("receiver", "shift_s", "model"))
            if opts and mode != "common_plus_model":
                raise ValueError(f"noise_overrides: {sorted(opts)} do not apply to replay "
                                 f"mode {mode!r} (keys {list(SESSION_REPLAY_KEYS)})")
            if mode == "common_plus_model" and mdl is not None and opts:
                mdl = (mdl if isinstance(mdl, GpsNoiseModel)
                       else GpsNoiseModel.load(mdl)).with_overrides(**opts)
            elif opts:
                raise ValueError(f"noise_overrides: {sorted(opts)} need a 'model' to override")
            obs, _ = replay_one(truth, session, mode=mode, rng=rng, receiver=receiver,
                                shift_s=shift_s, model=mdl, config=config)
            obs.setflags(write=False)
            return obs
    else:
        model = noise if isinstance(noise, GpsNoiseModel) else GpsNoiseModel.load(noise)
        if noise_overrides:
            model = model.with_overrides(**noise_overrides)
        dt = float(np.median(np.diff(truth.t))) if truth.n > 1 else 1.0
        lost = (model.power_failure_start_s + model.power_failure_duration_s
                if model.power_failure_duration_s > 0 else 0.0)
        duration = max(float(session_s), truth.n * dt) + lost
        session = synthesize_session(model, config, duration, rng,
                                     rate_hz=1.0 / dt).after_power_failure()
    if session.n < truth.n:
        raise ValueError(f"noise: session of {session.n} samples is shorter than the run "
                         f"({truth.n} samples); use a longer session")
    start = int(rng.integers(0, session.n - truth.n + 1))
    obs = replay(truth, session, start=start, mode="error")
    obs.setflags(write=False)
    return obs
