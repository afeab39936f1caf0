"""Trackers as objects (estimator.trackers, issue 24): every built-in class gives what
track() gives, bit for bit; options are validated where a tracker is built and errors name
the option; a user's tracker loads by "module:Name" or an entry point and runs; every loader
failure is a ValueError naming the technique and the problem."""

from __future__ import annotations

import dataclasses
import importlib.metadata

import numpy as np
import pandas as pd
import pytest
from synth_tracks import corner_path, straight

from estimator.memo import TrackCache
from estimator.pose_filter import PoseFilterParams
from estimator.track_options import METHODS, DynamicWindow, FitOptions, LagCorrection, MotionOptions
from estimator.trackers import (
    BUILTIN_TRACKERS,
    ENTRY_POINT_GROUP,
    FixedLagSmootherTracker,
    MotionCompensatedTracker,
    NaiveTracker,
    PoseFilterTracker,
    RtsSmootherTracker,
    Tracker,
    TrackerLoadError,
    WindowTracker,
    base,
    load_tracker,
    run_tracker,
)
from estimator.tracking import track


def _noisy_corner():
    cfg, t, _cg, yaw, turning, obs = corner_path(leg_steps=40, turn_steps=6)
    rng = np.random.default_rng(5)
    obs = obs + rng.normal(0.0, 0.3, obs.shape)
    obs[10:13, 1] = np.nan
    return cfg, t, yaw, turning, obs


# ----------------------------------------------------------------------------- built-ins
def _families(turning, yaw):
    """(method, track() keyword arguments) covering every option family; the class takes
    the same names (rng, turning and lag heading are the recording's)."""
    g = np.random.default_rng
    return [
        ("window", {"window": 8}),
        ("window", {"window": 8, "weighting": "huff"}),
        ("window", {"window": 8, "weighting": "huff:3.5", "solver": "elastic"}),
        ("window", {"window": 8, "weighting": "random", "rng": g(1)}),
        ("window", {"window": 8, "weighting": "huber", "solver": "slsqp",
                    "fit": FitOptions(warm_start=True, maxiter=20)}),
        ("window", {"window": 8, "lag_correction": "course"}),
        ("window", {"window": 8, "lag_correction": LagCorrection(heading=yaw)}),
        ("window", {"window": 8, "lag_correction": True, "dynamic_window": 1,
                    "turning": turning}),
        ("window", {"window": 8, "dynamic_window": DynamicWindow(2, "refill"),
                    "turning": "detect"}),
        ("motion_compensated", {"window": 8, "weighting": "huff"}),
        ("motion_compensated", {"window": 8, "motion": MotionOptions(yaw_rate=True)}),
        ("naive", {"window": 8, "dynamic_window": 1, "turning": turning}),
        ("ekf", {"window": 3}),
        ("ekf_fixed_lag", {"window": 3, "filter_params": PoseFilterParams(lag_s=2.0)}),
        ("ekf_smoother", {"window": 3}),
        ("ekf_ieks", {"window": 3}),
    ]


def _assert_same(a: pd.DataFrame, b: pd.DataFrame) -> None:
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert repr(a.attrs) == repr(b.attrs)


@pytest.mark.parametrize("i", range(15))
def test_every_builtin_through_its_class_equals_track(i):
    cfg, t, yaw, turning, obs = _noisy_corner()
    method, kw = _families(turning, yaw)[i]
    via_track = track(t, obs, cfg, method=method, **kw)
    _, kw = _families(turning, yaw)[i]          # a fresh generator for the random weights
    tracker = BUILTIN_TRACKERS[method](**kw)
    assert tracker.name == method
    _assert_same(tracker.track(t, obs, cfg), via_track)


def test_the_families_cover_every_method_but_the_optional_peer():
    assert {m for m, _ in _families(None, None)} == set(METHODS) - {"gtsam"}


def test_registry_is_the_methods_and_each_class_is_a_tracker():
    assert tuple(BUILTIN_TRACKERS) == METHODS
    for name, cls in BUILTIN_TRACKERS.items():
        assert cls.name == name
        assert dataclasses.is_dataclass(cls)
        assert isinstance(cls(), Tracker)


@pytest.mark.parametrize("cls, kw", [
    (WindowTracker, {"window": 6, "weighting": "huff"}),
    (WindowTracker, {"window": 6, "solver": "elastic", "lag_correction": "pose"}),
    (MotionCompensatedTracker, {"window": 6, "weighting": "huff"}),
    (PoseFilterTracker, {"window": 2}),
    (RtsSmootherTracker, {"window": 2}),
    (FixedLagSmootherTracker, {"window": 2}),
])
def test_a_cache_changes_no_number_and_is_used(cls, kw):
    cfg, t, _yaw, _turning, obs = _noisy_corner()
    tracker = cls(**kw)
    plain = tracker.track(t, obs, cfg)
    cache = TrackCache()
    first = tracker.track(t, obs, cfg, cache=cache)
    assert sum(len(m) for m in cache.memos().values()) > 0
    again = tracker.track(t, obs, cfg, cache=cache)
    _assert_same(first, plain)
    _assert_same(again, plain)


def test_techniques_sharing_a_cache_share_its_rows_and_change_no_number():
    """The sweep's order on one noise key (issue 27): the rows of one fit (CG, heading) and
    the lag correction's inputs are computed once for None / LC / LC (course) / LC with the
    truth's heading, and once for Dyn / LC + Dyn / LC (course) + Dyn; the filter's antenna
    positions once for its windows; every table equals its uncached one, bit for bit."""
    cfg, t, yaw, turning, obs = _noisy_corner()
    dyn = {"dynamic_window": 1, "turning": turning}
    runs = [(WindowTracker, {"weighting": "huff"}),
            (WindowTracker, {"weighting": "huff", "lag_correction": "pose"}),
            (WindowTracker, {"weighting": "huff", "lag_correction": "course"}),
            (WindowTracker, {"weighting": "huff",
                             "lag_correction": LagCorrection(mode="pose", heading=yaw)}),
            (WindowTracker, {"weighting": "huff", **dyn}),
            (WindowTracker, {"weighting": "huff", "lag_correction": "pose", **dyn}),
            (WindowTracker, {"weighting": "huff", "lag_correction": "course", **dyn}),
            (PoseFilterTracker, {}), (PoseFilterTracker, {"window": 1}),
            (RtsSmootherTracker, {}), (RtsSmootherTracker, {"window": 1})]
    cache = TrackCache()
    for cls, kw in runs:
        tracker = cls(**{"window": 6, **kw})
        _assert_same(tracker.track(t, obs, cfg, cache=cache), tracker.track(t, obs, cfg))
    # poses: the fixed and the dynamic rows' heading, the filter's and the smoother's
    # positions; lag: the fixed rows' inputs and the dynamic rows'
    assert (len(cache.poses), len(cache.lag)) == (4, 2)


@pytest.mark.parametrize("solver, batch", [("elastic", "elastic_batch"),
                                           ("procrustes", "procrustes_poses")])
def test_a_dynamic_track_reuses_the_fixed_windows_fits(monkeypatch, solver, batch):
    """With the fixed window-s fit memoised, a dynamic-window track fits only its rows of
    other sizes (each window is fitted on its own, so the others are the fixed fit's
    rows): the same table as uncached, bit for bit, with fewer windows fitted."""
    import estimator.trackers._windows as tw

    cfg, t, _yaw, turning, obs = _noisy_corner()
    solved = []
    real = getattr(tw, batch)

    def counting(means, *a, **kw):
        solved.append(len(means))
        return real(means, *a, **kw)

    monkeypatch.setattr(tw, batch, counting)
    fixed = WindowTracker(window=6, solver=solver, weighting="huff")
    dyn = WindowTracker(window=6, solver=solver, weighting="huff", dynamic_window=1,
                        turning=turning)
    plain = dyn.track(t, obs, cfg)
    n_rows = solved[-1]
    cache = TrackCache()
    fixed.track(t, obs, cfg, cache=cache)
    solved.clear()
    _assert_same(dyn.track(t, obs, cfg, cache=cache), plain)
    n_small = int((plain["window"] < 6).sum())
    assert solved == [n_small] and 0 < n_small < n_rows


def test_a_tracker_is_frozen_with_keyword_only_options():
    tr = WindowTracker(window=5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        tr.window = 6
    with pytest.raises(TypeError):
        WindowTracker(5)
    with pytest.raises(TypeError, match="speed"):
        WindowTracker(speed=1)


def test_options_are_normalised_where_the_tracker_is_built():
    tr = WindowTracker(weighting="huff:3.5", lag_correction=True, dynamic_window=1,
                       turning="detect")
    assert tr.weighting.scheme == "huff" and tr.weighting.huff_threshold == 3.5
    assert tr.lag_correction.mode == "pose"
    assert tr.dynamic_window == DynamicWindow(1)
    assert WindowTracker(lag_correction=False).lag_correction is None
    assert PoseFilterTracker().filter_params == PoseFilterParams()


@pytest.mark.parametrize("cls, kw, field", [
    (WindowTracker, {"window": 0}, "window"),
    (WindowTracker, {"window": 2.5}, "window"),
    (WindowTracker, {"solver": "ipopt"}, "solver"),
    (WindowTracker, {"weighting": "tukey"}, "weighting"),
    (WindowTracker, {"weighting": "random"}, "rng"),
    (WindowTracker, {"fit": {"eps": 0.1}}, "fit"),
    (WindowTracker, {"solver": "elastic", "fit": FitOptions(warm_start=True)}, "warm_start"),
    (WindowTracker, {"lag_correction": "yes"}, "lag_correction"),
    (WindowTracker, {"dynamic_window": 1}, "turning"),
    (WindowTracker, {"window": 5, "dynamic_window": 6, "turning": "detect"},
     "dynamic_window"),
    (WindowTracker, {"turning": "detect"}, "turning"),
    (WindowTracker, {"dynamic_window": 1, "turning": "guess"}, "turning"),
    (WindowTracker, {"dynamic_window": 1, "turning": np.zeros((3, 2), bool)}, "turning"),
    (WindowTracker, {"dynamic_window": DynamicWindow(1, detector={"window": 3}),
                     "turning": np.zeros(5, bool)}, "detector"),
    (WindowTracker, {"layout_check": "yes"}, "layout_check"),
    (MotionCompensatedTracker, {"motion": {"yaw_rate": True}}, "motion"),
    (NaiveTracker, {"turning": np.zeros(5, bool)}, "turning"),
    (PoseFilterTracker, {"filter_params": {"lag_s": 1.0}}, "filter_params"),
    (RtsSmootherTracker, {"window": -1}, "window"),
])
def test_option_errors_name_the_option(cls, kw, field):
    with pytest.raises((ValueError, TypeError), match=field):
        cls(**kw)


def test_options_that_depend_on_the_recording_are_checked_at_track():
    cfg, t, _cg, _yaw, obs = straight(n=30)
    with pytest.raises(ValueError, match="window"):
        WindowTracker(window=31).track(t, obs, cfg)
    with pytest.raises(ValueError, match="turning"):
        WindowTracker(dynamic_window=1, turning=np.zeros(29, bool)).track(t, obs, cfg)
    with pytest.raises(ValueError, match="lag_heading"):
        WindowTracker(lag_correction=LagCorrection(heading=np.zeros(29))).track(t, obs, cfg)
    with pytest.raises(ValueError, match="velocity_span"):
        WindowTracker(lag_correction=LagCorrection(velocity_span=31)).track(t, obs, cfg)
    with pytest.raises(TypeError, match="cache"):
        WindowTracker(weighting="huff").track(t, obs, cfg, cache={})


@pytest.mark.parametrize("kw, field", [
    ({"method": "ekf", "fit": FitOptions()}, "fit"),
    ({"method": "naive", "motion": MotionOptions()}, "motion"),
    ({"method": "ekf_smoother", "lag_correction": "course"}, "lag_correction"),
    ({"method": "motion_compensated", "solver": "slsqp"}, "solver"),
    ({"method": "naive", "weighting": "huff"}, "weighting"),
])
def test_track_names_an_argument_the_method_does_not_take(kw, field):
    cfg, t, _cg, _yaw, obs = straight(n=30)
    with pytest.raises(ValueError, match=f"^{field}: .*{kw['method']}"):
        track(t, obs, cfg, window=5, **kw)


def test_track_ignores_an_unused_generator_as_before():
    cfg, t, _cg, _yaw, obs = straight(n=30)
    a = track(t, obs, cfg, window=5, method="ekf", rng=np.random.default_rng(0))
    _assert_same(a, PoseFilterTracker(window=5).track(t, obs, cfg))


# ----------------------------------------------------------------------------- plug-ins
def test_a_plugin_loads_by_import_path_and_runs():
    cfg, t, _cg, yaw, obs = straight(n=40)
    tr = load_tracker("plugin_tracker:MeanTracker", {"rear": 0, "front": 1})
    assert isinstance(tr, Tracker)
    df = run_tracker(tr, t, obs, cfg, cache=TrackCache())     # no cache keyword: not passed
    assert list(df.columns) == ["t", "cg_x", "cg_y", "yaw"] and len(df) == 40
    np.testing.assert_array_equal(df[["cg_x", "cg_y"]].to_numpy(), np.nanmean(obs, axis=1))
    # noise-free straight run: the antenna pair gives the heading to round-off (1e-12 rad)
    np.testing.assert_allclose(df["yaw"].to_numpy(), yaw, atol=1e-12)


def test_a_plugin_options_table_is_validated():
    with pytest.raises(TrackerLoadError, match=r"plugin_tracker:MeanTracker.*unknown option"
                                               r".*'speed'.*takes \['front', 'rear'\]"):
        load_tracker("plugin_tracker:MeanTracker", {"speed": 1.0})
    with pytest.raises(TrackerLoadError, match=r"plugin_tracker:MeanTracker.*bad options.*"
                                               r"rear.*-1"):
        load_tracker("plugin_tracker:MeanTracker", {"rear": -1})
    with pytest.raises(TrackerLoadError, match="options must be a table"):
        load_tracker("plugin_tracker:MeanTracker", [("rear", 1)])
    with pytest.raises(TrackerLoadError, match="option names must be strings"):
        load_tracker("plugin_tracker:MeanTracker", {1: 2})


@pytest.mark.parametrize("technique, problem", [
    ("plugin_tracker:", "not an import path"),
    (":MeanTracker", "not an import path"),
    ("plugin tracker:MeanTracker", "not an import path"),
    ("plugin_tracker:Mean-Tracker", "not an import path"),
    ("no_such_module_h7:Tracker", "cannot import module 'no_such_module_h7'"),
    ("plugin_tracker:Nope", "module 'plugin_tracker' has no attribute 'Nope'"),
    ("plugin_tracker:not_a_class", "names a function, not a tracker class"),
    ("plugin_tracker:NotATracker", "class NotATracker has no track"),
    ("plugin_tracker:BadSignature", r"BadSignature.track must take \(t, obs, config\)"),
    ("no such name", "neither an import path"),
    ("h7_unknown_tracker", "not a built-in tracker nor an entry point"),
])
def test_loader_errors_name_the_technique_and_the_problem(technique, problem):
    with pytest.raises(ValueError, match=problem) as err:
        load_tracker(technique)
    assert isinstance(err.value, TrackerLoadError)
    assert repr(technique) in str(err.value)


def test_a_technique_must_be_a_string():
    with pytest.raises(TrackerLoadError, match="technique: expected a string"):
        load_tracker(3)


def test_builtin_names_load_with_an_options_table():
    tr = load_tracker("window", {"window": 5, "weighting": "huff", "lag_correction": "course"})
    assert isinstance(tr, WindowTracker) and tr.window == 5
    with pytest.raises(TrackerLoadError, match=r"'ekf'.*unknown option.*'weighting'"):
        load_tracker("ekf", {"weighting": "huff"})
    with pytest.raises(TrackerLoadError, match=r"'window'.*bad options.*solver"):
        load_tracker("window", {"solver": "ipopt"})


def _fake_entry_points(monkeypatch, *pairs):
    eps = [importlib.metadata.EntryPoint(name=n, value=v, group=ENTRY_POINT_GROUP)
           for n, v in pairs]
    monkeypatch.setattr(base, "_entry_points", lambda: eps)


def test_entry_point_lookup_by_name(monkeypatch):
    _fake_entry_points(monkeypatch, ("mean", "plugin_tracker:MeanTracker"),
                       ("other", "plugin_tracker:NotATracker"))
    tr = load_tracker("mean", {"front": 2})
    assert type(tr).__name__ == "MeanTracker" and tr.front == 2
    cfg, t, _cg, _yaw, obs = straight(n=12)
    assert len(run_tracker(tr, t, obs, cfg)) == 12
    with pytest.raises(TrackerLoadError, match="'other'.*has no track"):
        load_tracker("other")
    with pytest.raises(TrackerLoadError, match=r"'absent'.*known: \[.*'mean'.*'window'"):
        load_tracker("absent")


def test_entry_point_problems_are_named(monkeypatch):
    _fake_entry_points(monkeypatch, ("twice", "plugin_tracker:MeanTracker"),
                       ("twice", "other_pkg:MeanTracker"), ("badvalue", "plugin_tracker"))
    with pytest.raises(TrackerLoadError, match="'twice'.*several entry points"):
        load_tracker("twice")
    with pytest.raises(TrackerLoadError, match="'badvalue'.*entry point value 'plugin_tracker'"):
        load_tracker("badvalue")


def test_the_real_entry_point_group_is_read():
    """Without the indirection replaced, the installed distributions are asked (none of the
    test environment's registers a tracker named like this)."""
    assert all(ep.group == ENTRY_POINT_GROUP for ep in base._entry_points())
    with pytest.raises(TrackerLoadError, match=ENTRY_POINT_GROUP):
        load_tracker("h7_no_such_entry_point")


class _Returns:
    def __init__(self, value):
        self.value = value

    def track(self, t, obs, config):
        return self.value


def test_run_tracker_checks_the_table():
    cfg, t, _cg, _yaw, obs = straight(n=10)
    with pytest.raises(TypeError, match="_Returns.track: must return a pandas.DataFrame"):
        run_tracker(_Returns([1, 2]), t, obs, cfg)
    with pytest.raises(ValueError, match=r"lacks column\(s\) \['yaw'\]"):
        run_tracker(_Returns(pd.DataFrame({"t": t, "cg_x": t, "cg_y": t})), t, obs, cfg)
    with pytest.raises(ValueError, match="11 rows for 10 epochs"):
        run_tracker(_Returns(pd.DataFrame(dict.fromkeys(("t", "cg_x", "cg_y", "yaw"),
                                                        np.r_[t, 0.0]))), t, obs, cfg)
    built_in = run_tracker(WindowTracker(window=3), t, obs, cfg, cache=TrackCache())
    _assert_same(built_in, track(t, obs, cfg, window=3))


def test_status_values_make_the_column_astype_str_makes():
    from estimator.trackers._common import status_values

    st = np.where(np.arange(50) % 7 == 0, "insufficient_data", "ok").astype(object)
    fast = pd.DataFrame({"s": status_values(st)})["s"]
    slow = pd.DataFrame({"s": st.astype(str)})["s"]
    assert fast.dtype == slow.dtype and fast.equals(slow)
    odd = np.array(["ok", None, 3], dtype=object)        # not all str: astype(str)
    assert status_values(odd).tolist() == ["ok", "None", "3"]


def test_table_is_the_dict_constructors_frame():
    """_common.table builds pd.DataFrame(cols) from one block per dtype: the same columns,
    dtypes, values and parquet bytes; odd columns take the dict constructor."""
    import io

    from estimator.trackers._common import table

    rng = np.random.default_rng(4)
    n = 60
    cols = {"t": rng.random(n), "window": np.full(n, 5), "solver_status":
            np.where(rng.random(n) < 0.2, "insufficient_data", "ok").astype(object),
            "turning": rng.random(n) < 0.5, "x_a": rng.random(n), "n_used": np.arange(n),
            "nis": np.where(rng.random(n) < 0.1, np.nan, rng.random(n)),
            "f32": rng.random(n).astype(np.float32)}
    for c in (cols, {**cols, "odd": np.array(["a", None] * 30, dtype=object)},
              {**cols, "mixed": np.array(["a", 3] * 30, dtype=object)},
              {**cols, "u": np.array(["a"] * n)}, {"t": np.arange(3.0)}):
        want, got = pd.DataFrame(c), table(c, len(next(iter(c.values()))))
        assert list(got.columns) == list(want.columns)
        assert got.dtypes.equals(want.dtypes) and got.equals(want)
        assert got.index.equals(want.index) and got.columns.dtype == want.columns.dtype
        if "mixed" in c:                # parquet refuses mixed objects: nothing to write
            continue
        a, b = io.BytesIO(), io.BytesIO()
        want.to_parquet(a)
        got.to_parquet(b)
        assert a.getvalue() == b.getvalue()
    with pytest.raises(ValueError):
        table({"t": np.arange(3.0), "u": np.arange(4.0)}, 3)
