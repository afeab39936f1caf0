"""Smoke test of the ultrasonic study (python -m experiments.ultrasonic) at tiny sizes."""

import json

import numpy as np
import pytest

from experiments import ultrasonic as study


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ultrasonic")
    spec = study.StudySpec(n_mc=3000, flight_duration_s=12.0)
    res = study.run(out, spec, identification=False, figures=True)
    return out, res


def test_outputs_written(quick_run):
    out, _res = quick_run
    for name in ("mc_table.csv", "mc_table.md", "mc_pixels.csv", "flight_stages.csv",
                 "flight_stages.md", "flight_series.csv", "README.md", "run_info.json",
                 "mc_mse_maps.png", "flight_ranges.png", "flight_position.png",
                 "flight_heading.png"):
        assert (out / name).stat().st_size > 0, name
    info = json.loads((out / "run_info.json").read_text())
    assert info["spec"]["n_mc"] == 3000
    assert "Part 3 not run" in (out / "README.md").read_text()


def _first_order_mse(spec, receivers, method):
    """Appendix B's totals predicted by first-order error propagation at the same points:
    per point sigma^2 (J'J)^-1 (the Cramer-Rao bound, reached by the exact three-receiver
    solutions and by converged range least squares) or, for linear LS, A+ Cov(b) A+' with
    b_i = (R_1^2 - R_{i+1}^2 + ...) / 2, aggregated as the study does (mean over the 1 m pixels
    of the per-pixel mean). Returns (x, y, z) in mm^2."""
    ss = np.random.SeedSequence(spec.seed)
    rng = np.random.default_rng(ss.spawn(2)[0])            # the study's Monte Carlo stream
    n = spec.n_mc
    P = np.empty((n, 3))
    P[:, :2] = rng.uniform(-spec.extent_m, spec.extent_m, size=(n, 2))
    P[:, 2] = spec.z_plane_m
    d = P[:, None, :] - receivers[None]
    r = np.linalg.norm(d, axis=2)
    if method == "linear_ls":
        Ap = np.linalg.pinv(receivers[1:] - receivers[0])
        D = np.zeros((n, len(receivers) - 1, len(receivers)))
        D[:, :, 0] = r[:, :1]
        D[:, np.arange(len(receivers) - 1), np.arange(1, len(receivers))] = -r[:, 1:]
        G = np.einsum("ij,njk->nik", Ap, D)
        cov = spec.mc_sigma_m ** 2 * np.einsum("nik,njk->nij", G, G)
    else:
        u = d / r[:, :, None]
        cov = spec.mc_sigma_m ** 2 * np.linalg.inv(np.einsum("nki,nkj->nij", u, u))
    nb = round(2 * spec.extent_m / spec.bin_m) + 1
    ix = np.clip(np.rint((P[:, 0] + spec.extent_m) / spec.bin_m).astype(int), 0, nb - 1)
    iy = np.clip(np.rint((P[:, 1] + spec.extent_m) / spec.bin_m).astype(int), 0, nb - 1)
    flat = ix * nb + iy
    count = np.bincount(flat, minlength=nb * nb)
    var = np.diagonal(cov, axis1=1, axis2=2)
    per_pixel = np.stack([np.bincount(flat, var[:, a], nb * nb) for a in range(3)], 1)
    return np.mean(per_pixel[count > 0] / count[count > 0, None], axis=0) * 1e6


def test_monte_carlo_matches_first_order_error_propagation(quick_run):
    """Every method's Appendix B MSE per axis against its first-order prediction (the
    Cramer-Rao bound for range least squares and the exact three-receiver solutions; the
    propagated covariance for linear LS), from the receivers and the 5 mm noise alone.
    Tolerance 15 %: the 3000-point Monte Carlo estimates each MSE with a relative standard
    error of about sqrt(2 / 3000) = 2.6 % (more through the uneven pixel counts), so 15 % is
    ~5 standard errors; a wrong noise level (x 1.4 in sigma), a wrong receiver set or a biased
    solver moves a total by far more. The plain NLS z is the exception by design: its mirror
    solutions (~10 m errors) exceed the first-order prediction by orders of magnitude."""
    from sim.ultrasonic import load_receivers

    _, res = quick_run
    spec = study.StudySpec(n_mc=3000, flight_duration_s=12.0)
    names, rec = load_receivers("montecarlo")
    tri = rec[[names.index(x) for x in study.MC_TRIPLE]]
    mc = res["mc"].set_index("method")
    cases = {"linear_ls": ("linear_ls", rec, "xyz"), "nonlinear_ls": ("nls", rec, "xy"),
             "nonlinear_ls_reflect": ("nls", rec, "xyz"), "closed_form": ("nls", tri, "xyz"),
             "cayley_menger": ("nls", tri, "xyz")}
    for method, (model, receivers, axes) in cases.items():
        pred = _first_order_mse(spec, receivers, model)
        row = mc.loc[study.MC_LABEL[method]]
        for a in axes:
            got = row[f"mse_{a}_mm2"]
            assert got == pytest.approx(pred["xyz".index(a)], rel=0.15), (method, a)
    nls = mc.loc[study.MC_LABEL["nonlinear_ls"]]
    assert nls["mse_z_mm2"] > 10 * _first_order_mse(spec, rec, "nls")[2]
    assert nls["mirror_side_pct"] > 0
    # CFP and CMD: the same three-sphere solution, identical totals up to rounding
    cfp, cmd = mc.loc[study.MC_LABEL["closed_form"]], mc.loc[study.MC_LABEL["cayley_menger"]]
    assert cfp["mse_total_mm2"] == pytest.approx(cmd["mse_total_mm2"], rel=1e-9)


def test_flight_filters_reduce_error(quick_run):
    _, res = quick_run
    fl = res["flight"]
    for gates in fl["gates"].unique():
        d = fl[fl["gates"] == gates].set_index("stage")
        assert d.loc["filter1+2 -> CMD", "rmse_3d_m"] <= d.loc["raw -> CMD", "rmse_3d_m"]
    assert np.isfinite(fl["heading_rmse_deg"]).all()


def test_same_seed_same_numbers(tmp_path):
    spec = study.StudySpec(n_mc=500, flight_duration_s=6.0)
    a = study.run(tmp_path / "a", spec, identification=False, figures=False)
    b = study.run(tmp_path / "b", spec, identification=False, figures=False)
    assert a["mc"].drop(columns="time_s").equals(b["mc"].drop(columns="time_s"))
    assert a["flight"].equals(b["flight"])


def test_cli_rejects_bad_args():
    with pytest.raises(SystemExit):
        study.main(["--n-mc", "0"])
    for extra in (["--quick"], ["--n-mc", "10"], ["--out", "x"], ["--no-identification"]):
        with pytest.raises(SystemExit):
            study.main(["--reference", *extra])


def test_smoke_run_never_writes_the_committed_reference(tmp_path, monkeypatch):
    """--quick (or any run without --reference) goes to the untracked default folder; the
    committed results/ultrasonic/ is written only by --reference with the default spec, and
    wall times go to the untracked timings.json, never into the tracked files."""
    calls = []
    monkeypatch.setattr(study, "DEFAULT_OUT", tmp_path / "local")
    monkeypatch.setattr(study, "run", lambda out, spec, **kw: calls.append((out, spec)) or {
        "mc": study.pd.DataFrame(), "flight": study.pd.DataFrame(), "timings": {}})
    study.main(["--quick"])
    study.main(["--reference"])
    (out_q, spec_q), (out_r, spec_r) = calls
    assert out_q == tmp_path / "local" and spec_q.n_mc == 5000
    assert out_r == study.REFERENCE_OUT and spec_r == study.StudySpec()
    assert study.DEFAULT_OUT != study.REFERENCE_OUT


def test_no_wall_times_in_tracked_outputs(quick_run):
    out, _ = quick_run
    assert "time_s" not in (out / "mc_table.csv").read_text().splitlines()[0]
    assert "timings" not in json.loads((out / "run_info.json").read_text())
    assert "Timings" not in (out / "README.md").read_text()
    assert json.loads((out / "timings.json").read_text())["monte_carlo_s"] > 0


def test_tightly_coupled_row_is_reported_per_gate_setting(quick_run):
    _, res = quick_run
    fl = res["flight"]
    tight = fl[fl["stage"] == study.TIGHT_STAGE]
    assert len(tight) == fl["gates"].nunique()
    assert np.isfinite(tight[["rmse_3d_m", "heading_rmse_deg"]].to_numpy()).all()


def test_joint_pose_row_is_reported_per_gate_setting(quick_run):
    """The beyond-the-thesis joint two-transmitter pose sits beside the thesis's rows, finite
    for every gate setting, and (six receivers, both transmitters' ranges at once) nearer
    than the thesis's per-transmitter CMD fixes behind the same gates."""
    _, res = quick_run
    fl = res["flight"]
    joint = fl[fl["stage"] == study.JOINT_STAGE].set_index("gates")
    assert len(joint) == fl["gates"].nunique()
    assert np.isfinite(joint[["rmse_3d_m", "heading_rmse_deg"]].to_numpy()).all()
    cmd = fl[fl["stage"] == "filter1+2 -> CMD"].set_index("gates")
    assert (joint["rmse_3d_m"] < cmd["rmse_3d_m"]).all()


def test_joint_pose_recovers_the_body_from_exact_ranges():
    """Exact ranges of a level body (front/rear transmitters 0.25 m either side of the
    origin) and exact heights: the pose to 1e-6 m / 1e-6 rad (LM tolerance 1e-8 relative,
    far below); a height off by 4 mm (under half the grouping step) moves x, y by less than
    4 x 4 mm (measured 12 mm: receivers 0.3-0.65 m off-axis under a body 2.5 m up turn a
    height error into a horizontal one ~2-3x larger, so the height matters)."""
    from types import SimpleNamespace

    from estimator.ranging import RangingConfig
    from sim.ultrasonic import load_receivers, true_ranges

    _, rec = load_receivers("flight")
    n = 30
    t = np.arange(n) * 0.1
    yaw = np.linspace(-3.0, 3.0, n)
    origin = np.column_stack([0.3 * np.cos(t), 0.2 * np.sin(t), np.full(n, 2.5)])
    lev = np.array([[0.25, 0.0, 0.0], [-0.25, 0.0, 0.0]])
    tx = origin[:, None, :] + np.stack([np.cos(yaw), np.sin(yaw), 0 * yaw], 1)[:, None, :] \
        * lev[None, :, :1]
    ranges = true_ranges(tx, rec)
    cfg = RangingConfig.appendix_c()
    for dz, tol in ((0.0, 1e-6), (0.004, 0.016)):
        kal = tx.copy()
        kal[..., 2] += dz
        res = SimpleNamespace(epochs=t, config=cfg, kalman=kal, ranges=ranges)
        pos, yw = study.joint_pose(res, rec)
        assert np.max(np.abs(pos[:, :2] - origin[:, :2])) < tol
        assert np.max(np.abs(np.angle(np.exp(1j * (yw - yaw))))) < 10 * tol


# ---------------------------------------------------------------- figure families (issue 28)
NEW_FIGURES = ("fig3_07_range_change_T20.png", "fig3_07_range_change_T21.png",
               "fig3_2_2_tx_difference.png", "appB_bias_quiver.png", "appB_mse_normalized.png",
               "appB_range_error_hist.png")


def _image_stats(path):
    """(height, width, share of chromatic pixels) of a PNG: pixels whose RGB channels differ
    by more than 0.1 (data drawn in colour; axes, text and grid are black/grey/white)."""
    import matplotlib.image as mpimg

    img = mpimg.imread(path)[..., :3]
    chroma = img.max(axis=-1) - img.min(axis=-1)
    return img.shape[0], img.shape[1], float((chroma > 0.1).mean())


@pytest.mark.parametrize("name", NEW_FIGURES)
def test_new_figure_families_written_and_not_blank(quick_run, name):
    """Each figure of experiments.ultrasonic_figures is written, at least 400 x 600 pixels, and
    carries data: at least 0.5 % of its pixels in colour (every family draws its bars,
    contours or arrows in colour; empty axes with titles and labels have none, checked on
    such a canvas: 0 %)."""
    out, _ = quick_run
    h, w, colour = _image_stats(out / name)
    assert h >= 400 and w >= 600, (name, h, w)
    assert colour > 0.005, (name, colour)


def test_image_check_rejects_an_empty_canvas(tmp_path):
    """The non-blank check above fails on six empty, titled axes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 2, figsize=(10, 8))
    for a in axes.ravel():
        a.set_title("T20R40 - T21R40")
    fig.savefig(tmp_path / "blank.png", dpi=100)
    plt.close(fig)
    assert _image_stats(tmp_path / "blank.png")[2] == 0.0


def test_range_error_counts_table(quick_run):
    """mc_range_errors.csv holds every Monte Carlo range error exactly once per receiver
    (3000 draws each) and, at sigma = 5 mm, the -30..30 mm window holds all but ~2e-9 of
    them; the bins are symmetric to within counting noise (|left - right| below 4 sqrt(n))."""
    import pandas as pd

    from experiments.ultrasonic_figures import range_error_counts

    out, _ = quick_run
    c = pd.read_csv(out / "mc_range_errors.csv")
    tot = c.groupby("receiver")["count"].sum()
    assert (tot == 3000).all() and len(tot) == 6
    inner = c[np.isfinite(c.lo_mm) & np.isfinite(c.hi_mm)]
    assert inner.groupby("receiver")["count"].sum().min() == 3000
    left = inner[inner.hi_mm <= 0]["count"].sum()
    right = inner[inner.lo_mm >= 0]["count"].sum()
    assert abs(left - right) < 4 * np.sqrt(left + right)
    with pytest.raises(ValueError, match="errors_m: expected shape"):
        range_error_counts(np.zeros((5, 3)), ["a", "b"])


def test_flight_series_keeps_both_transmitters(quick_run):
    """T21's (rear) raw ranges are saved beside T20's, so the difference histogram is drawn
    from data: the true T20 - T21 difference never exceeds the 0.5 m separation."""
    import pandas as pd

    out, _ = quick_run
    s = pd.read_csv(out / "flight_series.csv")
    for nm in ("R40", "R45"):
        d = s[f"range_true_front_{nm}"] - s[f"range_true_rear_{nm}"]
        assert d.abs().max() <= 0.5 + 1e-9
        assert s[f"range_raw_rear_{nm}"].notna().mean() > 0.5
