"""Ultrasonic range model: HX19 Tx/Rx ranges with noise, spikes, stale values and dropouts
(thesis 003, Sections 3.2.1-3.2.2, Figures 3.6-3.8, Appendix B noise level).

* :func:`load_receivers` reads a receiver layout (``models/receivers/<name>.toml``, metres).
* :class:`UltrasonicNoiseModel` holds the fault model (``models/noise/<name>.toml``, every key
  validated, unknown keys rejected).
* :func:`simulate_ranges` turns transmitter truth ``(n, 2, 3)`` and receivers ``(k, 3)`` into
  observed ranges ``(n, 2, k)``.
* :func:`sample_times` draws uneven sample times for truth that is evenly sampled.

Sampling times. The quadcopter truth (``sim.quadcopter``) is already logged at uneven sensor
times; :func:`simulate_ranges` evaluates the ranges at exactly those times (it never
resamples), so the unevenness comes from the truth. For truth on an even grid, draw times with
:func:`sample_times` (intervals uniform in ``[min_interval_s, max_interval_s]``) and interpolate
the truth there first. Stale values (``hold_rate``) model the DAQ repeating a pair's previous
value when it missed an update, which is the other face of uneven sampling in Section 3.2.1.

Order of faults per Tx/Rx sample: dropout (NaN, Markov bursts) first; of the remaining samples
a fraction ``hold_rate`` repeats the last fresh value of that pair; every fresh sample gets
Gaussian noise (truncated at ``max_error_m`` when that is > 0) and a fraction ``spike_rate`` of
fresh samples a spike. ``return_faults=True`` also returns the per-sample fault codes
(:data:`CLEAN`, :data:`SPIKE`, :data:`HELD`, :data:`DROPOUT`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from estimator._checks import check_fields, check_real
from estimator.model_files import MODELS_DIR, read_model_toml

__all__ = [
    "CLEAN",
    "DROPOUT",
    "HELD",
    "NOISE_DIR",
    "RECEIVERS_DIR",
    "SPIKE",
    "UltrasonicNoiseModel",
    "load_receivers",
    "sample_times",
    "simulate_ranges",
    "true_ranges",
]

RECEIVERS_DIR = MODELS_DIR / "receivers"
NOISE_DIR = MODELS_DIR / "noise"

CLEAN, SPIKE, HELD, DROPOUT = 0, 1, 2, 3


def load_receivers(name_or_path: str | Path = "montecarlo", *,
                   translate: bool = True) -> tuple[tuple[str, ...], np.ndarray]:
    """Receiver layout from ``models/receivers/<name>.toml`` (or a path).

    Returns ``(names, positions)`` with positions ``(k, 3)`` metres. ``translate=True`` adds
    the file's ``translation_m`` (Appendix B centres its array this way).
    """
    data, p = read_model_toml(name_or_path, RECEIVERS_DIR, "receivers")
    allowed = {"name", "description", "source", "names", "positions_m", "translation_m"}
    unknown = set(data) - allowed
    if unknown:
        raise ValueError(f"{p}: unknown keys {sorted(unknown)}")
    for key in ("names", "positions_m"):
        if key not in data:
            raise ValueError(f"{p}: missing key {key!r}")
    names = tuple(str(s) for s in data["names"])
    pos = np.asarray(data["positions_m"], dtype=float)
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] != len(names):
        raise ValueError(f"{p}: positions_m must be ({len(names)}, 3), got {pos.shape}")
    if len(set(names)) != len(names):
        raise ValueError(f"{p}: names must be unique, got {names}")
    if not np.all(np.isfinite(pos)):
        raise ValueError(f"{p}: positions_m must be finite")
    if translate and "translation_m" in data:
        tr = np.asarray(data["translation_m"], dtype=float)
        if tr.shape != (3,) or not np.all(np.isfinite(tr)):
            raise ValueError(f"{p}: translation_m must be 3 finite numbers, got {tr.tolist()}")
        pos = pos + tr
    return names, pos


@dataclass(frozen=True)
class UltrasonicNoiseModel:
    """Range fault model; see ``models/noise/ultrasonic.toml`` for every field's meaning,
    unit and source. Validated on construction (ValueError names the field)."""

    name: str = "ultrasonic"
    description: str = ""
    sigma_m: float = 0.005
    max_error_m: float = 0.015
    spike_rate: float = 0.01
    spike_min_m: float = 0.3
    spike_max_m: float = 5.0
    spike_positive_fraction: float = 0.7
    hold_rate: float = 0.03
    dropout_rate: float = 0.02
    dropout_mean_length: float = 3.0
    min_interval_s: float = 0.03
    max_interval_s: float = 0.10

    def __post_init__(self) -> None:
        # one validation rule for every numeric field (estimator._checks): a real number, never
        # a bool, finite, in its range; TypeError / ValueError name the field and the value
        inf = float("inf")
        bounds = {  # field: (lo, hi, lo_open, hi_open)
            "sigma_m": (0, inf, False, False), "max_error_m": (0, inf, False, False),
            "spike_rate": (0, 1, False, False), "spike_min_m": (0, inf, False, False),
            "spike_max_m": (0, inf, False, False),
            "spike_positive_fraction": (0, 1, False, False),
            "hold_rate": (0, 1, False, True), "dropout_rate": (0, 1, False, True),
            "dropout_mean_length": (1, inf, False, False),
        }
        for name, (lo, hi, lo_open, hi_open) in bounds.items():
            v = check_real(getattr(self, name), name, lo=lo, hi=hi, lo_open=lo_open,
                           hi_open=hi_open)
            object.__setattr__(self, name, v)
        check_fields(self, ("min_interval_s", "max_interval_s"))      # finite, > 0
        for name in ("min_interval_s", "max_interval_s"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if self.spike_max_m < self.spike_min_m:
            raise ValueError(f"spike_max_m: must be >= spike_min_m ({self.spike_min_m}), "
                             f"got {self.spike_max_m}")
        if self.max_interval_s < self.min_interval_s:
            raise ValueError(f"max_interval_s: must be >= min_interval_s "
                             f"({self.min_interval_s}), got {self.max_interval_s}")
        if self.dropout_enter_prob >= 1.0 and self.dropout_rate > 0:
            raise ValueError(f"dropout_rate: {self.dropout_rate} is unreachable with "
                             f"dropout_mean_length {self.dropout_mean_length} (entry "
                             "probability would exceed 1)")

    @classmethod
    def load(cls, name_or_path: str | Path = "ultrasonic") -> UltrasonicNoiseModel:
        """Read ``models/noise/<name>.toml`` (or a path); unknown keys are rejected."""
        data, p = read_model_toml(name_or_path, NOISE_DIR, "noise model",
                                  known_glob="ultrasonic*.toml")
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"{p}: unknown keys {sorted(unknown)}")
        return cls(**data)

    def replace(self, **changes) -> UltrasonicNoiseModel:
        """A copy with some fields changed (validated)."""
        vals = {f.name: getattr(self, f.name) for f in fields(self)}
        vals.update(changes)
        return type(self)(**vals)

    @property
    def dropout_exit_prob(self) -> float:
        """P(next sample fresh | this one dropped) = 1 / mean burst length."""
        return 1.0 / self.dropout_mean_length

    @property
    def dropout_enter_prob(self) -> float:
        """P(next sample dropped | this one fresh), giving the stationary fraction
        ``dropout_rate`` = enter / (enter + exit)."""
        r = self.dropout_rate
        return min(1.0, r * self.dropout_exit_prob / (1.0 - r))


def true_ranges(tx_positions: np.ndarray, receivers: np.ndarray) -> np.ndarray:
    """Exact Tx/Rx distances: tx (n, T, 3), receivers (k, 3) -> (n, T, k) metres."""
    tx = np.asarray(tx_positions, dtype=float)
    rec = np.asarray(receivers, dtype=float)
    if tx.ndim != 3 or tx.shape[2] != 3:
        raise ValueError(f"tx_positions: expected shape (n, T, 3), got {tx.shape}")
    if rec.ndim != 2 or rec.shape[1] != 3:
        raise ValueError(f"receivers: expected shape (k, 3), got {rec.shape}")
    if not (np.all(np.isfinite(tx)) and np.all(np.isfinite(rec))):
        raise ValueError("tx_positions/receivers: must be finite")
    d = tx[:, :, None, :] - rec[None, None, :, :]
    return np.sqrt(np.einsum("ntkc,ntkc->ntk", d, d))


def _markov_dropouts(n: int, c: int, model: UltrasonicNoiseModel,
                     rng: np.random.Generator) -> np.ndarray:
    """(n, c) bool bursts from a two-state chain started in its stationary distribution."""
    if model.dropout_rate == 0 or n == 0:
        return np.zeros((n, c), dtype=bool)
    p_in, p_out = model.dropout_enter_prob, model.dropout_exit_prob
    u = rng.random((n, c))
    state0 = rng.random(c) < model.dropout_rate
    if p_out == 1.0:
        # memoryless case: independent Bernoulli samples with P = p_in / (p_in + 1) = rate
        return u < model.dropout_rate
    out = np.empty((n, c), dtype=bool)
    s = state0
    for i in range(n):
        s = np.where(s, u[i] >= p_out, u[i] < p_in)
        out[i] = s
    return out


def simulate_ranges(t: np.ndarray, tx_positions: np.ndarray, receivers: np.ndarray,
                    model: UltrasonicNoiseModel, rng: np.random.Generator, *,
                    return_faults: bool = False):
    """Observed ranges from transmitter truth (thesis 003, Section 3.2.2, Figs 3.6-3.8).

    t (n,) s strictly increasing (only validated: faults are per sample); tx_positions
    (n, T, 3) m (T = 2 transmitters for the quadcopter); receivers (k, 3) m; model; rng.
    Returns ranges (n, T, k) m with NaN for dropouts; with ``return_faults=True`` the tuple
    ``(ranges, codes)`` with fault codes (n, T, k) int8 (CLEAN, SPIKE, HELD, DROPOUT).
    """
    tt = np.asarray(t, dtype=float)
    if tt.ndim != 1:
        raise ValueError(f"t: expected shape (n,), got {tt.shape}")
    if tt.size > 1 and not np.all(np.diff(tt) > 0):
        raise ValueError("t: must be strictly increasing")
    if not isinstance(model, UltrasonicNoiseModel):
        raise ValueError(f"model: expected UltrasonicNoiseModel, got {type(model).__name__}")  # noqa: TRY004 (DESIGN: ValueError)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")  # noqa: TRY004 (DESIGN: ValueError)
    truth = true_ranges(tx_positions, receivers)
    if truth.shape[0] != tt.size:
        raise ValueError(f"tx_positions: {truth.shape[0]} samples for {tt.size} times")
    n, T, k = truth.shape
    c = T * k
    flat = truth.reshape(n, c)

    # Gaussian noise (truncated at +/- max_error_m when > 0)
    if model.sigma_m == 0:
        noise = np.zeros((n, c))
    elif model.max_error_m > 0:
        b = model.max_error_m / model.sigma_m
        from scipy import stats  # here, not at import: scipy.stats costs ~0.5 s

        noise = stats.truncnorm.rvs(-b, b, scale=model.sigma_m, size=(n, c), random_state=rng)
    else:
        noise = rng.normal(0.0, model.sigma_m, size=(n, c))

    dropped = _markov_dropouts(n, c, model, rng)
    held = (rng.random((n, c)) < model.hold_rate) & ~dropped
    held[:1] = False                                # nothing to repeat at the first sample
    fresh = ~dropped & ~held
    spiked = (rng.random((n, c)) < model.spike_rate) & fresh
    size = rng.uniform(model.spike_min_m, model.spike_max_m, size=(n, c))
    positive = rng.random((n, c)) < model.spike_positive_fraction
    spike = np.where(positive, size, -np.minimum(size, flat))

    obs = flat + noise + np.where(spiked, spike, 0.0)
    obs = np.maximum(obs, 0.0) if model.sigma_m > 0 else obs   # noise cannot make r < 0
    # stale values: repeat the last fresh value of that channel (forward fill)
    idx = np.where(fresh, np.arange(n)[:, None], -1)
    last_fresh = np.maximum.accumulate(idx, axis=0)
    no_fresh_yet = held & (last_fresh < 0)
    held &= ~no_fresh_yet                             # a channel with no fresh value yet
    fresh |= no_fresh_yet                             # reports fresh (noise already applied)
    src = np.where(held, last_fresh, np.arange(n)[:, None])
    obs = np.take_along_axis(obs, np.maximum(src, 0), axis=0)
    obs[dropped] = np.nan

    out = obs.reshape(n, T, k)
    if not return_faults:
        return out
    codes = np.full((n, c), CLEAN, dtype=np.int8)
    codes[spiked] = SPIKE
    codes[held] = HELD
    codes[dropped] = DROPOUT
    return out, codes.reshape(n, T, k)


#: Most samples :func:`sample_times` draws (a day at 100 Hz): more is a unit typo, refused
#: before any allocation.
MAX_SAMPLES = 10_000_000


def sample_times(duration_s: float, model: UltrasonicNoiseModel,
                 rng: np.random.Generator, t0: float = 0.0) -> np.ndarray:
    """Uneven sample times in [t0, t0 + duration_s]: intervals uniform in
    [min_interval_s, max_interval_s] (Section 3.2.2: at most about 0.1 s). Returns (n,) s."""
    duration_s = check_real(duration_s, "duration_s", lo=0.0, lo_open=True)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")  # noqa: TRY004 (DESIGN: ValueError)
    m = int(np.ceil(duration_s / model.min_interval_s)) + 1
    if m > MAX_SAMPLES:
        raise ValueError(f"duration_s: {duration_s!r} s at >= {model.min_interval_s} s per "
                         f"sample is more than {MAX_SAMPLES:.0e} samples; simulate a shorter "
                         "flight")
    dts = rng.uniform(model.min_interval_s, model.max_interval_s, size=m)
    t = t0 + np.concatenate([[0.0], np.cumsum(dts)])
    return t[t <= t0 + duration_s]
