"""Transfer-function identification of the simulated quadcopter (thesis 003, Section 3.3).

``python -m experiments.identification [--out results/ultrasonic] [--seed 0] [--noise-m 0.01]
[--quick]`` (also part 3 of ``python -m experiments.ultrasonic``).

For each command channel the simulator's open-loop impulse response from hover
(:func:`sim.quadcopter.impulse_response`) is fitted with the thesis's form by
:func:`estimator.sysid.fit_transfer_function`:

============  ================  ================================================  ===========
axis          form              model                                             thesis
============  ================  ================================================  ===========
thrust        ``two_poles``     K e^{-Td s} / (s (1 + Tp1 s)(1 + Tp2 s))           3.3.1, 3.15
pitch         ``second_order``  K e^{-Td s} / (s (1 + 2 zeta Tw s + (Tw s)^2))     3.3.2, 3.18
yaw_rate      ``one_pole``      K e^{-Td s} / (s (1 + Tp1 s))                      3.3.3, 3.21
============  ================  ================================================  ===========

Three fits per axis:

* ``clean``: the simulator's noise-free response (what the simulator's chain really is);
* ``noisy``: the same response plus white Gaussian measurement noise, ``noise_m`` metres on
  altitude / position (one transmitter's coordinate, as the thesis used T20's) and
  ``sqrt(2) noise_m / 0.5`` rad on heading (the atan2 of two transmitters 0.5 m apart with
  independent noise, small-angle); one realisation from ``seed`` is tabulated with its
  intervals and identifiability flags;
* a Monte Carlo over ``n_mc`` further noise realisations (mean, std of each estimate and the
  fraction of runs in which it was flagged identifiable).

Validation: the simulator is also run with a *step* on the same channel (held from the pulse
start to the end of the record) and compared with the identified (clean) model's prediction
of it: the figures' left panels (the thesis's Figs 3.15, 3.18, 3.21 are the identified
models' step responses) and the ``step_fit_pct`` column (fit percent on data not used for
fitting). The right panels overlay the impulse data and the fitted responses (like Figs 3.14,
3.17, 3.20) and the unit-gain step responses ``y / K`` of the thesis's and the identified
models (gains are not comparable: the thesis's inputs are normalised stick deflections and its
outputs millimetres / degrees).

Outputs in ``out_dir``: ``identification.csv`` (one row per axis and parameter),
``identification.md``, ``identification_series.csv`` (the time series the figures are drawn
from; re-plotting with :func:`plot_identification` never re-simulates) and
``identification_<axis>.png``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from estimator.sysid import (
    FORMS,
    equivalent_lag,
    fit_transfer_function,
    simulate,
    step_response,
)
from experiments.provenance import git_describe

__all__ = ["AXIS_FORMS", "THESIS", "main", "plot_identification", "run_identification"]

REPO = Path(__file__).resolve().parents[1]
AXIS_FORMS = {"thrust": "two_poles", "pitch": "second_order", "yaw_rate": "one_pole"}
TX_SEPARATION_M = 0.5  # thesis 003 Section 3.2.2, Figure 3.3
REL_TOL = 0.25  # identifiability threshold, as fit_transfer_function's default

#: The thesis's printed identified values (003_691aa933e2e3c7e2.txt, Section 3.3). K is in
#: the thesis's units: output mm (altitude, position) or degrees (heading) per second per
#: unit of the normalised stick input ((U - median U) / max |U - median U|, Appendix C).
#: No fit percentages are printed in the text (Figs 3.14, 3.17, 3.20 are images).
THESIS: dict[str, dict] = {
    "thrust": {
        "section": "3.3.1", "figure": "3.15",
        "params": {"K": 1856.4, "Tp1": 0.40885, "Tp2": 0.42283, "Td": 0.6585},
        "K_unit": "mm/s per normalised stick",
        "note": "Td is printed as 0.6585 in the parameter list and as 0.6858 in the final "
                "equation G_thrust(s); the table uses the parameter list.",
    },
    "pitch": {
        "section": "3.3.2", "figure": "3.18",
        "params": {"K": 3425.9, "Tw": 5.4414, "zeta": 0.40287, "Td": 0.36505},
        "K_unit": "mm/s per normalised stick",
        "note": "",
    },
    "yaw_rate": {
        "section": "3.3.3", "figure": "3.21",
        "params": {"K": 91.258, "Tp1": 1.8439, "Td": 0.0044},
        "K_unit": "deg/s per normalised stick",
        "note": "",
    },
}
_OUT_UNIT = {"thrust": "m", "pitch": "m", "yaw_rate": "rad"}
_IN_UNIT = {"thrust": "hover-thrust fraction", "pitch": "rad tilt", "yaw_rate": "rad/s"}
_K_UNIT = {"thrust": "m/s per hover-thrust fraction", "pitch": "m/s per rad",
           "yaw_rate": "(rad/s) per (rad/s)"}
_PARAM_UNIT = {"Tp1": "s", "Tp2": "s", "Tw": "s", "zeta": "-", "Td": "s", "lag": "s"}


def _lag(form: str, p: Mapping[str, float]) -> float:
    """Total lag Td + D'(0) (see :func:`estimator.sysid.equivalent_lag`)."""
    if form == "two_poles":
        return p["Td"] + p["Tp1"] + p["Tp2"]
    if form == "second_order":
        return p["Td"] + 2.0 * p["zeta"] * p["Tw"]
    return p["Td"] + p["Tp1"]

#: (axis, kind) -> (t, u, y): "impulse" = the fitted experiment, "step" = validation.
Responses = Mapping[tuple[str, str], tuple[np.ndarray, np.ndarray, np.ndarray]]


def simulator_responses(*, quick: bool = False) -> dict[tuple[str, str], tuple]:
    """Impulse and step responses of the three channels from :mod:`sim.quadcopter`.

    The step is the impulse experiment with the pulse held to the end of the record.
    """
    from sim.quadcopter import impulse_response  # experiments may import sim

    out: dict[tuple[str, str], tuple] = {}
    for axis in AXIS_FORMS:
        r = impulse_response(axis)
        out[(axis, "impulse")] = (np.asarray(r.t), np.asarray(r.u), np.asarray(r.y))
        if not quick:
            pre = float(r.t[np.argmax(r.u != 0)])
            s = impulse_response(axis, pulse_s=float(r.t[-1]) - pre + 1.0)
            out[(axis, "step")] = (np.asarray(s.t), np.asarray(s.u), np.asarray(s.y))
    return out


def simulator_constants() -> dict[str, dict[str, tuple[float, str]]]:
    """The simulated chain's own constants that map onto the thesis's parameters.

    Read from :mod:`sim.quadcopter` (stick channels, controller gains) and the compiled model
    (mass, inertia, drag, motor lag, actuator delay). ``{axis: {param: (value, how)}}``;
    parameters with no single counterpart in the chain are left out.

    The total lag (ramp asymptote ``K (t - lag)``, see :func:`estimator.sysid.equivalent_lag`)
    adds up along the chain: the open thrust path adds the motor lag and actuator delay; a
    closed proportional loop adds only its own ``D'(0)`` (rate loop ``I / (k I + d)``,
    attitude loop ``1 / k_att``), the motor lag and actuator delay inside it do not add (to
    first order; their effect in the yaw loop is ``d (tau_m + tau_a) / (k I + d)`` ~ 2e-4 s).
    """
    from sim.quadcopter import STICK_CHANNELS, Gains, load_model

    m = load_model()
    body = m.body("quad")
    mass, izz = float(body.mass[0]), float(body.inertia[2])
    drag_xy = float(m.numeric("drag_xy").data[0])
    drag_z = float(m.numeric("drag_z").data[0])
    drag_rot = float(m.numeric("drag_rot").data[0])
    motor = float(m.actuator_dynprm[0, 0])
    act_delay = float(m.actuator_delay[0]) + float(m.opt.timestep)  # setting + one step
    g = -float(m.opt.gravity[2])
    gains = Gains()
    th, pi, yw = STICK_CHANNELS["thrust"], STICK_CHANNELS["pitch"], STICK_CHANNELS["yaw_rate"]
    tz, txy = mass / drag_z, mass / drag_xy
    k_i = gains.k_rate_yaw * izz
    rate_lag = (izz + drag_rot * (motor + act_delay)) / (k_i + drag_rot)
    att_lag = 1.0 / gains.k_att
    poles = sorted((th.tau_s, tz))
    return {
        "thrust": {
            "K": (g * tz, "g m / drag_z"),
            "Tp1": (poles[0], "smaller of stick filter and m / drag_z"),
            "Tp2": (poles[1], "larger of stick filter and m / drag_z"),
            "Td": (th.delay_s + motor + act_delay,
                   (f"link {th.delay_s:g} s + motor lag {motor:g} s + actuator delay "
                   f"{act_delay:g} s (open path; the lag folded into the delay)")),
            "lag": (th.delay_s + motor + act_delay + th.tau_s + tz, "sum of the above"),
        },
        "pitch": {
            "K": (g * txy, "g m / drag_xy (small tilt)"),
            "lag": (pi.delay_s + att_lag + txy,
                    (f"link {pi.delay_s:g} s + attitude loop 1 / k_att {att_lag:g} s + "
                    f"m / drag_xy {txy:.4g} s")),
        },
        "yaw_rate": {
            "K": (k_i / (k_i + drag_rot), "closed rate loop k I / (k I + drag_rot)"),
            "Tp1": (yw.tau_s, "stick filter"),
            "Td": (yw.delay_s + rate_lag,
                   f"link {yw.delay_s:g} s + closed rate loop's lag {rate_lag:.4g} s"),
            "lag": (yw.delay_s + yw.tau_s + rate_lag, "sum of the above"),
        },
    }


def _pick(fit, lag_entry: dict | None, key: str, what: str, i: int) -> object:
    """One cell of the table: a parameter's (or the total lag's) value, CI bound or flag."""
    if fit is None:
        return None if what == "identifiable" else float("nan")
    if key == "lag":
        v = lag_entry[what]
        return v[i] if what == "ci" else v
    if what == "value":
        return fit.params[key]
    if what == "ci":
        return fit.intervals[key][i]
    return fit.identifiable[key]


def _noise_sigma(axis: str, noise_m: float) -> float:
    return math.sqrt(2.0) * noise_m / TX_SEPARATION_M if axis == "yaw_rate" else noise_m


def _fit_pct(y: np.ndarray, yhat: np.ndarray) -> float:
    den = np.linalg.norm(y - y.mean())
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den)) if den > 0 else float("nan")


def run_identification(
    out_dir: str | Path,
    *,
    seed: int = 0,
    noise_m: float = 0.01,
    quick: bool = False,
    n_mc: int | None = None,
    n_starts: int | None = None,
    responses: Responses | Callable[[], Responses] | None = None,
) -> pd.DataFrame:
    """Identify the three channels, write the table, report and figures; return the table.

    out_dir : folder for ``identification.{md,csv}``, ``identification_series.csv`` and
        ``identification_<axis>.png`` (created if missing).
    seed : seeds the noise and the fits' random starts
        (``numpy.random.SeedSequence([seed, axis index, run])``).
    noise_m : white measurement noise, metres (>= 0; 0 skips the noisy fits).
    quick : fewer starts (3), fewer Monte Carlo runs (5), no step validation run.
    n_mc, n_starts : override the Monte Carlo size (default 20, quick 5) and starts per fit
        (default 8, quick 3).
    responses : ``{(axis, "impulse"|"step"): (t, u, y)}`` or a callable returning it; default
        :func:`simulator_responses`. (Tests pass synthetic responses here.)

    Returns one row per (axis, parameter) with the thesis's value, the clean and noisy fits,
    the noisy fit's interval and flag, Monte Carlo summaries, fit percentages and fit times.
    """
    if not (isinstance(noise_m, (int, float)) and math.isfinite(noise_m) and noise_m >= 0):
        raise ValueError(f"noise_m: must be a finite number >= 0, got {noise_m!r}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: must be a non-negative integer, got {seed!r}")
    n_mc = (5 if quick else 20) if n_mc is None else n_mc
    n_starts = (3 if quick else 8) if n_starts is None else n_starts
    if not (isinstance(n_mc, (int, np.integer)) and n_mc >= 0):
        raise ValueError(f"n_mc: must be an integer >= 0, got {n_mc!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    constants = None
    if responses is None:
        data = simulator_responses(quick=quick)
        constants = simulator_constants()
    elif callable(responses):
        data = dict(responses())
    else:
        data = dict(responses)
    sim_time = time.perf_counter() - t_start

    rows: list[dict] = []
    series: list[pd.DataFrame] = []
    summary: dict[str, dict] = {}
    for ai, (axis, form) in enumerate(AXIS_FORMS.items()):
        if (axis, "impulse") not in data:
            raise ValueError(f"responses: missing ({axis!r}, 'impulse')")
        t, u, y = (np.asarray(a, dtype=float) for a in data[(axis, "impulse")])

        def rng_for(run: int, _ai: int = ai) -> np.random.Generator:
            return np.random.default_rng(np.random.SeedSequence([seed, _ai, run]))

        clean = fit_transfer_function(t, u, y, form, n_starts=n_starts, rng=rng_for(0),
                                      rel_tol=REL_TOL)
        sigma = _noise_sigma(axis, noise_m)
        noisy = None
        mc: list = []
        if noise_m > 0:
            g = rng_for(1)
            y_noisy = y + sigma * g.standard_normal(y.size)
            noisy = fit_transfer_function(t, u, y_noisy, form, n_starts=n_starts, rng=g,
                                          rel_tol=REL_TOL)
            for run in range(n_mc):
                g = rng_for(2 + run)
                mc.append(fit_transfer_function(t, u, y + sigma * g.standard_normal(y.size),
                                                form, n_starts=n_starts, rng=g,
                                                rel_tol=REL_TOL))
        else:
            y_noisy = None

        step_pct = float("nan")
        frame = {"axis": axis, "kind": "impulse", "t": t, "u": u, "y": y,
                 "y_clean_fit": clean.y_hat}
        if noisy is not None:
            frame["y_noisy"] = y_noisy
            frame["y_noisy_fit"] = noisy.y_hat
        series.append(pd.DataFrame(frame))
        if (axis, "step") in data:
            ts, us, ys = (np.asarray(a, dtype=float) for a in data[(axis, "step")])
            pred = simulate(ts, us, form, clean.params) + clean.offset
            step_pct = _fit_pct(ys, pred)
            series.append(pd.DataFrame({"axis": axis, "kind": "step", "t": ts, "u": us,
                                        "y": ys, "y_clean_fit": pred}))
        # unit-gain step responses of the thesis's and the identified model (Figs 3.15...)
        tu = np.arange(0.0, 10.0 + 1e-9, 0.02)
        th = THESIS[axis]["params"]
        series.append(pd.DataFrame({
            "axis": axis, "kind": "unit_step", "t": tu, "u": np.ones_like(tu),
            "y": step_response(tu, form, {**th, "K": 1.0}),
            "y_clean_fit": step_response(tu, form, {**clean.params, "K": 1.0})}))

        summary[axis] = {"clean": clean, "noisy": noisy, "mc": mc, "sigma": sigma,
                         "step_pct": step_pct}
        const = constants.get(axis, {}) if constants else {}
        lag_th = _lag(form, th)
        per_fit = {}
        for name, f in (("clean", clean), ("noisy", noisy)):
            if f is None:
                continue
            lag, (lo, hi) = equivalent_lag(f)
            per_fit[name] = {"value": lag, "ci": (lo, hi),
                             "identifiable": bool(hi - lo <= 2 * REL_TOL * max(lag, f.dt))}
        mc_lag = [equivalent_lag(f)[0] for f in mc]
        fits = {"clean": clean, "noisy": noisy}
        for k in (*FORMS[form], "lag"):
            cell = {(w, what, i): _pick(fits[w], per_fit.get(w), k, what, i)
                    for w in fits for what in ("value", "ci", "identifiable") for i in (0, 1)}
            mc_vals = mc_lag if k == "lag" else [f.params[k] for f in mc]
            sim_v, sim_note = const.get(k, (float("nan"), ""))
            row = {
                "axis": axis, "form": form, "parameter": k,
                "unit": _K_UNIT[axis] if k == "K" else _PARAM_UNIT[k],
                "thesis": lag_th if k == "lag" else th[k],
                "thesis_unit": THESIS[axis]["K_unit"] if k == "K" else _PARAM_UNIT[k],
                "simulator": sim_v, "simulator_note": sim_note,
                "clean": cell["clean", "value", 0],
                "clean_ci_low": cell["clean", "ci", 0],
                "clean_ci_high": cell["clean", "ci", 1],
                "clean_identifiable": cell["clean", "identifiable", 0],
                "noisy": cell["noisy", "value", 0],
                "noisy_ci_low": cell["noisy", "ci", 0],
                "noisy_ci_high": cell["noisy", "ci", 1],
                "noisy_identifiable": cell["noisy", "identifiable", 0],
                "mc_mean": float(np.mean(mc_vals)) if mc else float("nan"),
                "mc_std": float(np.std(mc_vals, ddof=1)) if len(mc) > 1 else float("nan"),
                "mc_identifiable_frac": float("nan") if not mc or k == "lag"
                else float(np.mean([f.identifiable[k] for f in mc])),
                "clean_fit_pct": clean.nrmse,
                "noisy_fit_pct": noisy.nrmse if noisy else float("nan"),
                "step_fit_pct": step_pct,
                "clean_status": clean.status,
                "noisy_status": noisy.status if noisy else "",
                "clean_fit_time_s": clean.elapsed_s,
                "noisy_fit_time_s": noisy.elapsed_s if noisy else float("nan"),
                "noise_sigma": sigma if noise_m > 0 else 0.0,
                "n_mc": len(mc),
            }
            rows.append(row)
    table = pd.DataFrame(rows)
    table.to_csv(out / "identification.csv", index=False)
    pd.concat(series, ignore_index=True).to_csv(out / "identification_series.csv",
                                                index=False, float_format="%.7g")
    meta = {"seed": seed, "noise_m": noise_m, "quick": quick, "n_mc": n_mc,
            "n_starts": n_starts, "code_version": git_describe(),
            "sim_time_s": sim_time, "total_time_s": time.perf_counter() - t_start,
            "source": "synthetic (passed in)" if responses is not None
            else "sim.quadcopter.impulse_response"}
    (out / "identification.md").write_text(_report(table, summary, meta))
    plot_identification(out)
    return table


def _fmt(v: float, nd: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "inf" if isinstance(v, float) and math.isinf(v) else "-"
    return f"{v:.{nd}g}"


def _report(table: pd.DataFrame, summary: dict, meta: dict) -> str:
    L = ["# Transfer-function identification (thesis 003, Section 3.3)", "",
         (f"Generated by `python -m experiments.identification` (`run_identification`): "
         f"seed {meta['seed']}, noise {meta['noise_m']} m, quick={meta['quick']}, "
         f"{meta['n_starts']} starts per fit, {meta['n_mc']} Monte Carlo runs, "
         f"code {meta['code_version']}. Data: {meta['source']} "
         f"({meta['sim_time_s']:.1f} s to simulate; {meta['total_time_s']:.1f} s in total "
         f"on a loaded 2-core machine)."), "",
         ("Method: `estimator.sysid.fit_transfer_function`: bounded least squares, exact "
         "input delay (zero-order-hold interval split), multi-start; fit % = 100 (1 - "
         "||y - y_hat|| / ||y - mean y||) as MATLAB's \"fit to estimation data\". Intervals "
         "are 95 % from the Jacobian; a parameter is flagged not identifiable when its "
         "half-width exceeds 25 % of max(|value|, dt) (dt for time parameters) or the "
         "Jacobian is rank deficient. *clean* = the simulator's noise-free response "
         "(its intervals reflect model mismatch, not noise); *noisy* = plus white noise "
         "(sigma in each section); MC = mean +- std over the Monte Carlo runs and the "
         "fraction flagged identifiable. The thesis prints no fit percentages in the text "
         "and its K is per normalised stick unit in mm/s or deg/s, so K is not comparable. "
         "*lag* = Td + Tp1 (+ Tp2) or Td + 2 zeta Tw: the step response's ramp asymptote "
         "is K (t - lag), a combination that stays determined when its parts trade off "
         "(interval by the delta method). *simulator constants* are the simulated chain's "
         "own values (`simulator_constants()`: stick channel, drag, motor lag, actuator "
         "delay); '-' where the chain has no single counterpart."),
         ""]
    for axis, form in AXIS_FORMS.items():
        s = summary[axis]
        th = THESIS[axis]
        c, n = s["clean"], s["noisy"]
        target = {"thrust": "altitude", "pitch": "x position", "yaw_rate": "heading"}[axis]
        L += [f"## {axis} -> {target} (`{form}`, Section {th['section']}, Fig {th['figure']})",
              ""]
        L += [f"Fit %: clean {c.nrmse:.2f}"
              + (f", noisy {n.nrmse:.2f} (sigma {s['sigma']:.4g} {_OUT_UNIT[axis]})"
                 if n else "")
              + (f", step validation {s['step_pct']:.2f}" if math.isfinite(s["step_pct"])
                 else "")
              + f". Fit time clean {c.elapsed_s:.3f} s"
              + (f", noisy {n.elapsed_s:.3f} s" if n else "")
              + f". Status clean `{c.status}`" + (f", noisy `{n.status}`" if n else "") + ".",
              ""]
        L += [("| parameter | thesis | simulator constants | clean fit [95 % CI] "
               "| noisy fit [95 % CI] | identifiable (clean / noisy / MC frac) "
               "| MC mean +- std |"),
              "|---|---|---|---|---|---|---|"]
        sub = table[table.axis == axis]
        for _, r in sub.iterrows():
            unit = r["unit"]
            thesis = f"{_fmt(r['thesis'], 5)} {r['thesis_unit']}" if r["parameter"] == "K" \
                else f"{_fmt(r['thesis'], 5)}"
            ci_c = f"[{_fmt(r['clean_ci_low'])}, {_fmt(r['clean_ci_high'])}]"
            ci_n = f"[{_fmt(r['noisy_ci_low'])}, {_fmt(r['noisy_ci_high'])}]"
            flags = (f"{'yes' if r['clean_identifiable'] else 'NO'} / "
                     + ("-" if r["noisy_identifiable"] is None
                        else ("yes" if r["noisy_identifiable"] else "NO"))
                     + f" / {_fmt(r['mc_identifiable_frac'], 2)}")
            simc = "-" if not math.isfinite(r["simulator"]) else (
                f"{_fmt(r['simulator'])} ({r['simulator_note']})")
            L.append(f"| {r['parameter']} ({unit}) | {thesis} | {simc} "
                     f"| {_fmt(r['clean'])} {ci_c} | "
                     f"{_fmt(r['noisy'])} {ci_n} | {flags} | "
                     f"{_fmt(r['mc_mean'])} +- {_fmt(r['mc_std'], 2)} |")
        L += [""]
        if form == "second_order":
            for name, f in (("clean", c), ("noisy", n)):
                if f is not None and f.params["zeta"] >= 1.0:
                    z, w = f.params["zeta"], f.params["Tw"]
                    r_ = math.sqrt(z * z - 1.0)
                    L += [(f"The {name} fit is overdamped (zeta >= 1): its quadratic factor "
                          f"is two real poles, {w * (z + r_):.4g} s and {w * (z - r_):.4g} s.")]
            L += [""]
        corr = [f"{a}/{b} rho={rho:+.3f}" for a, b, rho in (n.correlated if n else ())]
        if corr:
            L += [f"Strongly correlated estimates (noisy fit): {', '.join(corr)}.", ""]
        if th["note"]:
            L += [f"Note: {th['note']}", ""]
        L += [f"![{axis}](identification_{axis}.png)", ""]
    L += _summary(table)
    return "\n".join(L) + "\n"


def _summary(table: pd.DataFrame) -> list[str]:
    """Comparison sentences; every number is read from this run's table."""
    L = ["## Summary", ""]
    for axis in AXIS_FORMS:
        sub = table[table.axis == axis].set_index("parameter")
        lag = sub.loc["lag"]
        sim = (f", the simulated chain's constants give {lag.simulator:.4g} s"
               if math.isfinite(lag.simulator) else "")
        line = (f"- **{axis}**: total lag thesis {lag.thesis:.4g} s{sim}, clean fit "
                f"{lag.clean:.4g} s")
        if math.isfinite(lag.noisy):
            line += (f", noisy fit {lag.noisy:.4g} s [{lag.noisy_ci_low:.4g}, "
                     f"{lag.noisy_ci_high:.4g}]")
        params = [k for k in sub.index if k not in ("K", "lag")]
        clean_no = [k for k in params if not sub.loc[k, "clean_identifiable"]]
        noisy_no = [k for k in params if sub.loc[k, "noisy_identifiable"] is not None
                    and not sub.loc[k, "noisy_identifiable"]]
        line += (f". Not identifiable: clean {', '.join(clean_no) or 'none'}; noisy "
                 f"{', '.join(noisy_no) or 'none'}.")
        L.append(line)
    L += ["", ("Gains K are in different units from the thesis's and are compared with the "
          "simulator's constants only. Time constants, delays and the total lag are "
          "comparable in seconds."), ""]
    return L


def plot_identification(out_dir: str | Path) -> list[Path]:
    """Draw ``identification_<axis>.png`` from ``identification_series.csv`` (no simulation).

    Left: the simulator's response to a step on the channel vs the identified model's
    prediction (when the step run exists) or, otherwise, the identified model's step
    response; middle: impulse data and fits; right: unit-gain step responses y/K of the
    thesis's and the identified model.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    s = pd.read_csv(out / "identification_series.csv")
    paths = []
    for axis in AXIS_FORMS:
        a = s[s.axis == axis]
        fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
        unit = _OUT_UNIT[axis]
        st = a[a.kind == "step"]
        if len(st):
            ax[0].plot(st.t, st.y, "k", lw=2, label="simulator, step input")
            ax[0].plot(st.t, st.y_clean_fit, "r--", label="identified model")
            ax[0].set_title(f"{axis}: response to a step (validation)")
        else:
            us = a[a.kind == "unit_step"]
            imp = a[a.kind == "impulse"]
            amp = float(np.max(np.abs(imp.u))) * float(np.sign(imp.u[imp.u != 0].iloc[0]))
            ax[0].set_title(f"{axis}: identified model, step of {amp:g}")
            tab = pd.read_csv(out / "identification.csv")
            K = float(tab[(tab.axis == axis) & (tab.parameter == "K")].clean.iloc[0])
            ax[0].plot(us.t, amp * K * us.y_clean_fit, "r", label="identified model")
        ax[0].set_xlabel("t (s)")
        ax[0].set_ylabel(f"output ({unit})")
        ax[0].legend()
        imp = a[a.kind == "impulse"]
        if "y_noisy" in imp and imp.y_noisy.notna().any():
            ax[1].plot(imp.t, imp.y_noisy, ".", color="0.6", ms=3, label="simulator + noise")
            ax[1].plot(imp.t, imp.y_noisy_fit, "b-", lw=1, label="fit to noisy")
        ax[1].plot(imp.t, imp.y, "k", lw=2, label="simulator")
        ax[1].plot(imp.t, imp.y_clean_fit, "r--", label="fit to clean")
        ax2 = ax[1].twinx()
        ax2.step(imp.t, imp.u, "g", where="post", lw=0.8, alpha=0.6)
        ax2.set_ylabel(f"input ({_IN_UNIT[axis]})", color="g")
        ax[1].set_title(f"{axis}: impulse response and fits")
        ax[1].set_xlabel("t (s)")
        ax[1].set_ylabel(f"output ({unit})")
        ax[1].legend(fontsize=8, loc="lower right")
        us = a[a.kind == "unit_step"]
        ax[2].plot(us.t, us.y, "k", label=f"thesis (Fig {THESIS[axis]['figure']} model)")
        ax[2].plot(us.t, us.y_clean_fit, "r--", label="identified from simulator")
        ax[2].set_title("unit-gain step response y / K")
        ax[2].set_xlabel("t (s)")
        ax[2].set_ylabel("y / K (s)")
        ax[2].legend()
        fig.tight_layout()
        p = out / f"identification_{axis}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    return paths


def main(argv: list[str] | None = None) -> int:
    """CLI: ``python -m experiments.identification``."""
    ap = argparse.ArgumentParser(prog="python -m experiments.identification",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(REPO / "results" / "ultrasonic"),
                    help="output folder (default results/ultrasonic)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise-m", type=float, default=0.01,
                    help="white measurement noise on position outputs, metres (default 0.01)")
    ap.add_argument("--quick", action="store_true", help="fewer starts/runs, no step run")
    a = ap.parse_args(argv)
    table = run_identification(a.out, seed=a.seed, noise_m=a.noise_m, quick=a.quick)
    cols = ["axis", "parameter", "thesis", "clean", "noisy", "noisy_identifiable",
            "clean_fit_pct"]
    print(table[cols].to_string(index=False))
    print(f"wrote {Path(a.out) / 'identification.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
