"""The compiled forward pass (estimator.pose_filter_kernel, issue 27) against the numpy
reference (``run_pose_filter(..., engine="numpy")``): the same decisions everywhere (status,
segment starts, fixes used and gated, displacements used, NIS dof), states, clones and
covariances within a tolerance in units of the estimate's own sd.

Tolerance: the two engines order the same arithmetic differently (the kernel updates in the
12-dimensional state space, the reference in the 2k-dimensional measurement space), so they
differ by rounding, amplified where the problem is ill-conditioned. It is: at a car's
standstill start with 2 mm RTK fixes the speed and acceleration are barely observable (the
stacked covariance's eigenvalues span 1e-16 to 40), and there the reference itself moves by
8e-4 sd, and its covariances by 1.4 % of their scale, when one fix moves by one picometre
(measured, seed 3). There the reference's own rounding error is the larger one: against
exact rational arithmetic (fractions.Fraction) its first update after the start (seed 0)
has a covariance entry 5.6 % of the scale ``sqrt(P_ii P_jj)`` off, the kernel's 7e-9
(measured). Bounds: states 0.05 sd and covariances 0.1 of the scale on the car cases
(measured <= 0.021 sd and 0.053, both in the first 10 epochs; after epoch 50 <= 6e-4 sd and
0.009), 1e-6 on the thesis paths (measured 3e-10 relative)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pose_scenes import kinematic_truth, noisy, vehicle_scene
from test_pose_filter import OFFSETS, _back_and_forth, _braking_car, _roll_back_then_drive
from test_vehicle_case import _standstill_gap_scene, _standstill_scene

import estimator.pose_filter as pf
import estimator.pose_filter_kernel as kn
from estimator.pose_filter import PoseFilterParams, run_pose_filter

REPO = Path(__file__).resolve().parents[1]
#: tolerances in sd of the reference's estimate (module docstring)
TOL_WELL = (1e-6, 1e-6)
TOL_CAR = (0.05, 0.1)              # (states in sd, covariances in their scale)
#: drive 0 with RTK, where the car starts after the 150 s stop (epochs ~830): with the joint
#: noise of a fix and its displacement (issue 25) the reference is ill-conditioned there, its
#: clone's yaw rate moves by 0.23 sd when one fix at epoch 700 moves by a picometre (the
#: kernel's by 3e-5 sd; measured); engines 0.27 sd and 0.21 of the scale apart (measured)
TOL_CAR_RESTART = (0.5, 0.5)


def _sd(P: np.ndarray) -> np.ndarray:
    return np.sqrt(np.abs(np.diagonal(P, axis1=1, axis2=2)))


def _close(a: np.ndarray, b: np.ndarray, P: np.ndarray, tol: float, what: str) -> None:
    """States a, b (n, 6) within tol sd of covariances P (n, 6, 6) (heading wrapped)."""
    assert (np.isfinite(a) == np.isfinite(b)).all(), f"{what}: NaN rows differ"
    d = np.abs(a - b)
    d[:, 2] = np.abs(np.angle(np.exp(1j * (a[:, 2] - b[:, 2]))))
    ok = np.isfinite(a[:, 0])
    worst = np.max(d[ok] / (_sd(P[ok]) + 1e-300)) if ok.any() else 0.0
    assert worst <= tol, f"{what}: {worst:.3g} sd apart (tolerance {tol})"


def _cov_close(A: np.ndarray, B: np.ndarray, tol: float, what: str) -> None:
    """Covariances within tol of sqrt(P_ii P_jj) (the scale of each entry)."""
    assert (np.isfinite(A) == np.isfinite(B)).all(), f"{what}: NaN rows differ"
    ok = np.isfinite(A[:, 0, 0])
    s = _sd(A[ok])
    scale = s[:, :, None] * s[:, None, :] + 1e-300
    worst = np.max(np.abs(A[ok] - B[ok]) / scale) if ok.any() else 0.0
    assert worst <= tol, f"{what}: {worst:.3g} of the scale apart (tolerance {tol})"


def assert_engines_agree(t, obs, off, params, tols):
    """Both engines on one recording: identical decisions, numbers within ``tols`` (states
    in sd, covariances and the NIS in their scale)."""
    tol, ctol = tols
    a = run_pose_filter(t, obs, off, params, engine="numpy")
    b = run_pose_filter(t, obs, off, params, engine="numba")
    for f in ("status", "segment_start", "n_used", "n_gated", "n_steps", "nis_dof"):
        bad = np.flatnonzero(getattr(a, f) != getattr(b, f))
        assert bad.size == 0, f"{f} differs first at epoch {bad[0]}"
    _close(a.states, b.states, a.covariances, tol, "states")
    _close(a.prev_states, b.prev_states, a.prev_covariances, tol, "prev_states")
    _cov_close(a.covariances, b.covariances, ctol, "covariances")
    _cov_close(a.prev_covariances, b.prev_covariances, ctol, "prev_covariances")
    cross = np.isfinite(a.cross_covariances[:, 0, 0])
    assert (cross == np.isfinite(b.cross_covariances[:, 0, 0])).all()
    s, sp = _sd(a.covariances[cross]), _sd(a.prev_covariances[cross])
    worst = np.max(np.abs(a.cross_covariances[cross] - b.cross_covariances[cross])
                   / (s[:, :, None] * sp[:, None, :] + 1e-300)) if cross.any() else 0.0
    assert worst <= ctol, f"cross_covariances: {worst:.3g}"
    nis = np.isfinite(a.nis)
    assert (nis == np.isfinite(b.nis)).all()
    # the NIS is a sum of squares of dof whitened innovations w: states tol sd apart move w
    # by up to tol sqrt(dof) in norm, so the NIS by 2 |w| tol sqrt(dof) (+ rounding, ctol of
    # its dof). An inconsistent epoch's NIS is large (seed 3's restart: 1283 for 16 dof) and
    # rounds in proportion: the engines were 1.61 apart there on an AMD EPYC host (0.13 %)
    dof, ref = a.nis_dof[nis], a.nis[nis]
    bound = ctol * dof + 2.0 * tol * np.sqrt(dof * np.abs(ref))
    worst = np.max(np.abs(ref - b.nis[nis]) - bound) if nis.any() else -1.0
    assert worst <= 0.0, f"nis: {worst:.3g} beyond the bound"
    return a, b


@pytest.mark.parametrize(("path", "seed"), [("square100", 1), ("square200", 2)])
def test_thesis_paths_agree(path, seed):
    """The thesis preset's scenes: rover_gps8 (one antenna dead) with replayed stationary
    GPS error on Path 1 and Path 2, limits from the controller."""
    truth, cfg, limits = kinematic_truth(path, "rover_gps8")
    obs = noisy(truth, cfg, "gps_stationary", seed)
    off = cfg.body_positions - cfg.cg_body
    a, _ = assert_engines_agree(truth.t, obs, off, PoseFilterParams.from_limits(limits),
                                TOL_WELL)
    assert (a.n_gated > 0).any()                       # the gates act on these paths


@pytest.mark.parametrize(("seed", "noise", "tols"), [(0, "rtk", TOL_CAR_RESTART),
                                                     (3, "rtk", TOL_CAR), (0, "shifted", TOL_CAR)])
def test_car_case_agrees(seed, noise, tols):
    """Issue 25's car (dropouts, a 150 s stop, a 34 s outage; RTK and consumer errors,
    every parameter estimated from the data): restarts, predicted rows, the standstill
    hold, re-initialisations and deletions all as in the reference."""
    _, t, obs, off = vehicle_scene(seed, noise)
    a, _ = assert_engines_agree(t, obs, off, PoseFilterParams(), tols)
    assert {"predicted", "ok"} <= set(a.status)


def test_standstill_start_and_gate_lock_out_agree():
    """The standstill start on the layout's heading and the lock-out recovered by a
    re-initialisation (tests/test_vehicle_case.py's scene), and the same scene with the
    monitor off (patched REINIT_EPOCHS reaches the kernel: the all-gated motion miss
    re-initialises, issue 25)."""
    t, obs, off, _, _ = _standstill_scene()
    a, _ = assert_engines_agree(t, obs, off, PoseFilterParams(), TOL_CAR)
    assert "reinit" in set(a.status) and "inconsistent" in set(a.status)
    import unittest.mock as um

    with um.patch.object(pf, "REINIT_EPOCHS", 10 ** 9):
        a, _ = assert_engines_agree(t, obs, off, PoseFilterParams(), TOL_CAR)
    assert "reinit" in set(a.status)          # the all-gated motion miss (issue 25)


def test_reverse_mode_flips_and_forward_mode_turn_round_agree():
    """Reverse mode's log-likelihood flip and forward mode's backward-travel flip."""
    cfg, t, cg, pos = _back_and_forth()
    obs = pos + np.random.default_rng(2).normal(0, 0.01, pos.shape)
    off = cfg.body_positions - cfg.cg_body
    assert_engines_agree(t, obs, off, PoseFilterParams(reverse=True, max_accel_mps2=3.0),
                         TOL_CAR)
    cfg, t, obs = _roll_back_then_drive()
    a, _ = assert_engines_agree(t, obs, cfg.body_positions - cfg.cg_body,
                                PoseFilterParams(sigma_abs_m=0.3, sigma_step_m=0.42), TOL_CAR)
    assert "flip_corrected" in set(a.status)


def test_outage_while_braking_and_an_hour_gap_agree():
    """Rows predicted through an outage (forward speed held at 0) and the prediction too
    wide for an update (MAX_PRIOR_RATIO: a restart "reset")."""
    t, obs, off, p = _braking_car()
    a, _ = assert_engines_agree(t, obs, off, p, TOL_CAR)
    assert (a.status == "predicted").sum() >= 10
    n = 60
    t = np.arange(float(n))
    t[30:] += 3600.0
    x = np.where(np.arange(n) < 30, t, t - 3600.0)
    obs = np.c_[x, np.zeros(n)][:, None, :] + OFFSETS[None]
    a, _ = assert_engines_agree(t, obs, OFFSETS, PoseFilterParams(), TOL_CAR)
    assert a.status[30] == "reset"


def test_no_gating_and_late_start_agree():
    """gate_prob = 1 (no gate, no deletions) and a recording starting with empty epochs."""
    truth, cfg, limits = kinematic_truth("square20", "rover_gps4")
    obs = noisy(truth, cfg, "gps_stationary", 4)
    obs[:7] = np.nan
    off = cfg.body_positions - cfg.cg_body
    for gp in (1.0, 0.999):
        a, _ = assert_engines_agree(truth.t, obs, off,
                                    PoseFilterParams.from_limits(limits, gate_prob=gp),
                                    TOL_WELL)
        assert (a.status[:7] == "no_data").all()


def test_kernel_layout_and_engine_argument():
    """The kernel's state layout is the module's; an unknown engine names the argument."""
    assert (kn.PX, kn.PY, kn.YAW, kn.V, kn.A, kn.OMEGA, kn.NX) == (
        pf.PX, pf.PY, pf.YAW, pf.V, pf.A, pf.OMEGA, pf.NX)
    assert len(kn.COLS) == kn.NC and max(kn.COLS) < 2 * kn.NX
    with pytest.raises(ValueError, match=r"engine: .*'fortran'"):
        run_pose_filter(np.arange(3.0), np.zeros((3, 4, 2)) + OFFSETS, OFFSETS,
                        engine="fortran")


_ALLOC_SCRIPT = """
import json
import numpy as np
from numba.core.runtime import rtsys
from estimator.pose_filter import PoseFilterParams, run_pose_filter
from estimator.pose_smoother import iterated_rts_smooth, rts_smooth
off = np.array({off!r})
rng = np.random.default_rng(0)
p = PoseFilterParams(sigma_abs_m=0.01, sigma_step_m=0.014)
out = []
for n in (60, 600):
    t = np.arange(float(n))
    yaw = 0.002 * t
    cg = np.c_[np.cumsum(2.0 * np.cos(yaw)), np.cumsum(2.0 * np.sin(yaw))]
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    obs = np.stack([cg[:, :1] + c * off[:, 0] - s * off[:, 1],
                    cg[:, 1:] + s * off[:, 0] + c * off[:, 1]], -1)
    obs = obs + rng.normal(0, 0.01, obs.shape)
    r = run_pose_filter(t, obs, off, p)            # compiled or loaded
    iterated_rts_smooth(r, t, obs, off, 2)
    a0 = rtsys.get_allocation_stats().alloc
    r = run_pose_filter(t, obs, off, p)
    a1 = rtsys.get_allocation_stats().alloc
    rts_smooth(r)
    iterated_rts_smooth(r, t, obs, off, 2)
    a2 = rtsys.get_allocation_stats().alloc
    assert (r.status == "ok").sum() > 0.8 * n
    out.append((a1 - a0, a2 - a1))
print(json.dumps(out))
"""


def test_compiled_passes_allocate_nothing_per_epoch():
    """The compiled forward pass, RTS and relinearised passes allocate their work arrays once
    per call, none per epoch (issue 27: ~49 allocations per epoch cost ~10 % of the car's
    forward pass, and with them its helpers' reference counting ~30 %): the runtime's
    allocation count (NUMBA_NRT_STATS) of a call is the same for 60 and 600 epochs of a
    gap-free drive."""
    env = {**os.environ, "NUMBA_NRT_STATS": "1", "NUMBA_DISABLE_JIT": "0"}
    res = subprocess.run([sys.executable, "-c", _ALLOC_SCRIPT.format(off=OFFSETS.tolist())],
                         check=True, env=env, cwd=REPO, timeout=600, capture_output=True,
                         text=True)
    (f60, s60), (f600, s600) = json.loads(res.stdout.strip().splitlines()[-1])
    assert f60 == f600 and s60 == s600, (f60, f600, s60, s600)


_SCRIPT = """
import sys, numpy as np
sys.path.insert(0, {tests!r})
from test_vehicle_case import _standstill_gap_scene, _standstill_scene
from estimator.pose_filter import run_pose_filter
t, obs, off, _, _ = _standstill_scene()
r = run_pose_filter(t, obs, off)
np.savez({out!r}, x=r.states, s=r.status.astype(str))
"""


def test_runs_the_same_without_the_jit(tmp_path):
    """NUMBA_DISABLE_JIT=1 (the kernel as plain Python, e.g. for a debugger): the same
    decisions and numbers to 1e-9 sd as compiled (the same operations; LLVM may contract
    or reorder none of them without fastmath, measured identical)."""
    out = {}
    for flag in ("0", "1"):
        f = tmp_path / f"jit{flag}.npz"
        env = {**os.environ, "NUMBA_DISABLE_JIT": flag}
        subprocess.run([sys.executable, "-c", _SCRIPT.format(tests=str(REPO / "tests"),
                                                              out=str(f))],
                       check=True, env=env, cwd=REPO, timeout=600)
        out[flag] = np.load(f)
    assert (out["0"]["s"] == out["1"]["s"]).all()
    np.testing.assert_allclose(out["0"]["x"], out["1"]["x"], rtol=0, atol=1e-9)
    assert math.isfinite(float(np.nanmax(out["0"]["x"][:, 0])))


@pytest.mark.parametrize("scene", ["square100", "car"])
def test_rts_engines_agree(scene):
    """The compiled RTS recursion against the numpy loop (the same operations per element,
    summed in another order): states within 1e-9 sd and covariances within 1e-9 of their
    scale (measured 2e-11 m and 4e-15 on the car: the backward recursion carries the
    rounding of the 6 x 6 products over ~1500 epochs)."""
    from estimator.pose_smoother import rts_smooth

    if scene == "car":
        _, t, obs, off = vehicle_scene(0, "rtk")
        p = PoseFilterParams()
    else:
        truth, cfg, limits = kinematic_truth(scene, "rover_gps8")
        t, obs = truth.t, noisy(truth, cfg, "gps_stationary", 1)
        off, p = cfg.body_positions - cfg.cg_body, PoseFilterParams.from_limits(limits)
    res = run_pose_filter(t, obs, off, p)
    a, b = rts_smooth(res, engine="numpy"), rts_smooth(res)
    _close(a.states, b.states, a.covariances, 1e-9, "smoothed states")
    _cov_close(a.covariances, b.covariances, 1e-9, "smoothed covariances")
    c = rts_smooth(res, covariances=False)
    np.testing.assert_array_equal(c.states, b.states)
    with pytest.raises(ValueError, match="engine: .*'gpu'"):
        rts_smooth(res, engine="gpu")


def test_car_case_consumer_hold_after_gap_agrees():
    """The cpm drive whose hold after an outage was fixed (issue 25, drive 7): the hold's
    gap-and-motion rule as in the reference, every status and decision alike."""
    _, t, obs, off = vehicle_scene(7, "common_plus_model")
    a, _ = assert_engines_agree(t, obs, off, PoseFilterParams(), TOL_CAR)
    assert {"predicted", "ok"} <= set(a.status)


def test_standstill_gap_bound_agrees():
    """The heading bound after a gap the car stood through (issue 25,
    ``_bound_after_standstill_gap``) as in the reference: forward pass and the iterated
    smoother's relinearised pass, on tests/test_vehicle_case.py's scene (the bound acts at
    epoch 52) and with the fixes moved in the gap (it does not)."""
    from estimator.pose_smoother import iterated_rts_smooth

    for jump in (0.0, 1.0):
        t, obs, off, _, p = _standstill_gap_scene(jump_m=jump)
        a, b = assert_engines_agree(t, obs, off, p, TOL_WELL)
        ia = iterated_rts_smooth(a, t, obs, off, 2, engine="numpy")
        ib = iterated_rts_smooth(a, t, obs, off, 2)
        _close(ia.states, ib.states, ia.covariances, TOL_WELL[0], "iterated states")
        _cov_close(ia.covariances, ib.covariances, TOL_WELL[1], "iterated covariances")


def test_jit_options_fall_back_when_numba_drops_its_internal():
    """``_nrt=False`` is a numba internal: the helpers take it only when the target options
    declare it, else numba's plain options (the same results, with reference counting), so
    a numba release without it still imports the kernel."""
    from estimator.pose_filter_kernel import _JIT_OPTIONS, jit_options

    class WithNrt:
        _nrt = None

    class WithoutNrt:
        pass

    assert jit_options(WithNrt) == {**_JIT_OPTIONS, "_nrt": False}
    assert jit_options(WithoutNrt) == _JIT_OPTIONS
    assert "_nrt" not in _JIT_OPTIONS
    numba_core_cpu = pytest.importorskip("numba.core.cpu")
    assert jit_options() == jit_options(numba_core_cpu.CPUTargetOptions)
