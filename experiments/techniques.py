"""The technique registry: every value of a spec's ``technique`` axis, defined once.

A technique is a way of running :func:`estimator.tracking.track` that a sweep compares with
the others: the dissertation's trackers (000_8f82f8df647bf685.txt: the sliding window of
Section 3.4.1, lag correction 3.4.2, dynamic window 3.4.2.1 and their combination, Tables
4.1/4.2), the trackers beyond it, and the oracle rows that feed the lag correction the
simulator's heading. Each :class:`Technique` says

- what it runs: the tracking method, the lag-correction variant and the heading of its
  step 5, whether the window is dynamic (:meth:`Technique.track_arguments` builds the
  arguments of ``track``);
- which spec axes apply (solver, weighting, the dynamic-window axes; the others are
  recorded as "-" so cells are not duplicated);
- whether it is an oracle (uses the truth: a diagnostic, never an estimator result);
- where it comes from (the section of the source, or the issue that added it);
- its rows in the tables: Tables 4.1/4.2 rows (label, mask), other readings of those rows,
  and its label in the heading table.

The spec validation (:mod:`experiments.spec`), the sweep's dispatch
(:mod:`experiments.sweep`), the table rows (:mod:`experiments.tables`) and the CLI help
derive from :data:`REGISTRY`; adding a technique is one entry here.

Plug-ins (a user's tracker, :mod:`estimator.trackers.base`) become entries of kind
"plugin" when a spec is loaded (:func:`plugin_entries`, from the spec's ``technique``
values and its ``[techniques."<name>"]`` tables): label from the class name or the table's
``label``, colour from :data:`PLUGIN_PALETTE` or the table's ``color``, one table row on the
full path; no solver, weighting or dynamic-window axis applies. :func:`technique` looks
them up beside the registry when given them.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from estimator.lag import LAG_MODES
from estimator.track_options import FILTER_METHODS, METHODS, WEIGHTED_METHODS

__all__ = ["DYNAMIC", "FILTER_TECHNIQUES", "KINDS", "LAG_HEADINGS", "NO_SOLVER", "NO_WEIGHTS",
           "ORACLE_TECHNIQUES", "REGISTRY", "TECHNIQUES", "PLUGIN_KEYS", "PLUGIN_PALETTE",
           "TURNING_SOURCES", "Technique", "course_pairs", "heading_rows", "is_plugin_name",
           "oracle_pairs", "plugin_entries", "plugin_label", "plugin_names", "plugins_in_results",
           "reading_rows", "table_rows", "technique", "techniques_help"]

#: What a technique is: a tracker of the dissertation, one beyond it, an oracle, or a
#: user's tracker loaded as a plug-in.
KINDS = ("thesis", "beyond", "oracle", "plugin")
#: Keys of a spec's ``[techniques."<name>"]`` table (:func:`plugin_entries`).
PLUGIN_KEYS = ("tracker", "options", "label", "color")
#: Colours of plug-in rows in figures, in the order the spec names them (none is a
#: registry colour: tab20's darker shades not taken by the built-ins).
PLUGIN_PALETTE = ("#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd",
                  "#e6550d", "#31a354")
#: Headings the lag correction can be fed in place of the estimated one: the simulator's
#: (or a recording reference's) true heading (oracle) or the pose filter's RTS-smoothed one.
LAG_HEADINGS = ("truth", "smoothed")
#: Where a dynamic-window technique takes its turning flags: the simulator's controller
#: (the dissertation's "control information"; a recording's reference turns) or the
#: estimate-based detector (:func:`estimator.tracking.detect_turning`).
TURNING_SOURCES = ("controller", "detector")


@dataclass(frozen=True)
class Technique:
    """One value of the ``technique`` axis (module docstring).

    name : the spec value. kind : one of :data:`KINDS`. source : the section of the source
    document or the issue it implements. summary : one line for the CLI help.
    method : :data:`estimator.track_options.METHODS`. lag : None or a lag-correction variant
    (:data:`estimator.lag.LAG_MODES`). lag_heading : None (the estimated heading) or one of
    :data:`LAG_HEADINGS`. dynamic : uses the dynamic window (Section 3.4.2.1).
    rows : its rows in Tables 4.1/4.2 style tables, (label, mask). readings : other readings
    of those rows, (label, mask, growth rule or None). heading_row : its label in the
    heading table (None: not listed).
    requires : an optional Python module it needs (e.g. "gtsam") and the pip extra, or None.
    short : its short label in figures (box-plot groups; ``\n`` breaks a line).
    color : its colour in figures (a Matplotlib colour string).
    oracle_of : for an oracle, the technique whose estimated heading it replaces with the
    truth (the pairing of the report's oracle probes). course_of : for the course-based
    lag correction, the as-written technique it is the variant of (the report's "(course)"
    claims). tracker, options : a plug-in's import path or entry-point name and its
    options as canonical JSON (kind "plugin" only; ``method`` is then "plugin").
    """

    name: str
    kind: str
    source: str
    summary: str
    method: str = "window"
    lag: str | None = None
    lag_heading: str | None = None
    dynamic: bool = False
    rows: tuple[tuple[str, str], ...] = ()
    readings: tuple[tuple[str, str, str | None], ...] = ()
    heading_row: str | None = None
    requires: tuple[str, str] | None = None
    short: str = ""
    color: str = "#7f7f7f"
    oracle_of: str | None = None
    course_of: str | None = None
    tracker: str | None = None
    options: str = "{}"

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: must be one of {KINDS}, got {self.kind!r}")
        if (self.kind == "plugin") != (self.tracker is not None):
            raise ValueError(f"{self.name}: a plug-in names its tracker, and only a plug-in")
        if self.kind == "plugin":
            return
        if self.method not in METHODS:
            raise ValueError(f"method: must be one of {METHODS}, got {self.method!r}")
        if self.lag is not None and (self.lag not in LAG_MODES or self.method != "window"):
            raise ValueError(f"lag: {self.lag!r} with method {self.method!r}")
        if self.lag_heading is not None and (self.lag_heading not in LAG_HEADINGS
                                             or self.lag != "pose"):
            raise ValueError(f"lag_heading: {self.lag_heading!r} with lag {self.lag!r}")
        if self.dynamic and self.method in FILTER_METHODS:
            raise ValueError(f"dynamic: not applicable to method {self.method!r}")
        if (self.kind == "oracle") != (self.lag_heading == "truth"):
            raise ValueError(f"{self.name}: a technique is an oracle exactly when it uses "
                             "the true heading")
        if (self.oracle_of is not None) != (self.kind == "oracle"):
            raise ValueError(f"{self.name}: an oracle names the technique it is the oracle "
                             "of (oracle_of), and only an oracle does")
        if self.course_of is not None and self.lag != "course":
            raise ValueError(f"{self.name}: course_of with lag {self.lag!r}")

    @property
    def oracle(self) -> bool:
        """It uses the truth: a diagnostic, never an estimator result."""
        return self.lag_heading == "truth"

    @property
    def uses_solver(self) -> bool:
        """The window solver applies (the ``solver`` axis)."""
        return self.method == "window" and self.kind != "plugin"

    @property
    def uses_weights(self) -> bool:
        """The observations are weighted (the ``weighting`` axis)."""
        return self.method in WEIGHTED_METHODS and self.kind != "plugin"

    @property
    def uses_filter(self) -> bool:
        """It runs the pose filter (and needs the vehicle's filter parameters)."""
        return self.method in FILTER_METHODS or self.lag_heading == "smoothed"

    def track_arguments(self, *, dyn_window: int, dyn_growth: str,
                        heading: Any = None) -> dict[str, Any]:
        """Keyword arguments of :func:`estimator.tracking.track` for this technique:
        ``method``, ``lag_correction`` and ``dynamic_window`` (the caller adds the window,
        weighting, solver, turning flags, rng and filter parameters).

        dyn_window, dyn_growth : the cell's small window and growth rule (dynamic
        techniques only). heading : (n,) rad, the heading of step 5 when ``lag_heading`` is
        set (the truth's for an oracle, the smoothed one otherwise); required then.
        """
        from estimator.track_options import DynamicWindow, LagCorrection

        kw: dict[str, Any] = {"method": self.method}
        if self.lag is not None:
            if self.lag_heading is not None and heading is None:
                raise ValueError(f"technique {self.name!r}: needs the {self.lag_heading} "
                                 "heading, and this cell has none")
            kw["lag_correction"] = LagCorrection(self.lag, heading=heading)
        if self.dynamic:
            kw["dynamic_window"] = DynamicWindow(dyn_window, dyn_growth)
        return kw


_LC_NO_TURNS = "no_turns_window"    # the faithful reading of "LC No Turns" (Section 4.12.2)

#: Every technique, in table order.
REGISTRY: tuple[Technique, ...] = (
    Technique("none", "thesis", "Sections 3.4.1, 4.12",
              "sliding-window fit (Eq. 3.9), no correction", rows=(("None", "full"),),
              heading_row="Window fit",
              short="None", color="#1f77b4"),
    Technique("lc", "thesis", "Section 3.4.2",
              "lag correction (LC) along the estimated orientation", lag="pose",
              rows=(("LC Full Path", "full"), ("LC No Turns", _LC_NO_TURNS)),
              readings=(("LC No Turns (turning epochs only)", "no_turns", None),),
              short="LC", color="#ff7f0e"),
    Technique("dyn", "thesis", "Section 3.4.2.1",
              "dynamic sliding window (Dyn SW): a small window on turning epochs", dynamic=True,
              rows=(("Dyn SW", "full"),),
              readings=(("Dyn SW (jump back)", "full", "jump"),),
              short="Dyn SW", color="#2ca02c"),
    Technique("lc+dyn", "thesis", "Sections 3.4.2, 3.4.2.1, 4.12.4",
              "lag correction and dynamic window (LC + Dyn SW)", lag="pose", dynamic=True,
              rows=(("LC + Dyn SW", "full"),),
              readings=(("LC + Dyn SW (jump back)", "full", "jump"),),
              short="LC+Dyn", color="#9467bd"),
    Technique("lc_course", "beyond", "issue 5",
              "lag correction along the estimated course (estimator.lag 'course')",
              lag="course", rows=(("LC (course)", "full"),),
              short="LC course", color="#bcbd22", course_of="lc"),
    Technique("lc_course+dyn", "beyond", "issue 5",
              "course lag correction and dynamic window", lag="course", dynamic=True,
              rows=(("LC (course) + Dyn SW", "full"),),
              short="LCc+Dyn", color="#17becf", course_of="lc+dyn"),
    Technique("motion_compensated", "beyond", "issue 5",
              "motion-compensated window: constant-velocity pose at the newest epoch",
              method="motion_compensated", rows=(("Motion-compensated", "full"),),
              heading_row="Motion-compensated",
              short="Motion-comp.", color="#8c564b"),
    Technique("ekf", "beyond", "issues 5, 14",
              "pose filter: causal EKF with the configuration as measurement model",
              method="ekf", rows=(("EKF (causal)", "full"),), heading_row="EKF (causal)",
              short="EKF", color="#e377c2"),
    Technique("naive", "beyond", "issue 5",
              "naive CG mean of the antennas' window means (no configuration)", method="naive",
              rows=(("Naive CG mean", "full"),),
              short="Naive", color="#7f7f7f"),
    Technique("ekf_fixed_lag", "beyond", "issue 14",
              "the pose filter's fixed-lag smoother", method="ekf_fixed_lag",
              rows=(("EKF fixed-lag smoother", "full"),),
              heading_row="EKF fixed-lag smoother",
              short="EKF fixed-lag", color="#c5b0d5"),
    Technique("ekf_smoother", "beyond", "issue 14",
              "the pose filter's full RTS smoother", method="ekf_smoother",
              rows=(("EKF RTS smoother", "full"),), heading_row="EKF RTS smoother",
              short="EKF RTS", color="#f7b6d2"),
    Technique("gtsam", "beyond", "issue 14",
              "GTSAM fixed-lag factor graph on the same measurements (peer)", method="gtsam",
              rows=(("GTSAM fixed-lag (peer)", "full"),),
              heading_row="GTSAM fixed-lag (peer)", requires=("gtsam", "gtsam"),
              short="GTSAM", color="#9edae5"),
    Technique("ekf_ieks", "beyond", "issue 25",
              "the pose filter's iterated RTS smoother (Gauss-Newton, relinearised)",
              method="ekf_ieks", rows=(("EKF iterated smoother", "full"),),
              heading_row="EKF iterated smoother", short="EKF IEKS", color="#ad494a"),
    Technique("lc_smoothed_heading", "beyond", "issue 14",
              "lag correction fed the pose filter's RTS-smoothed heading", lag="pose",
              lag_heading="smoothed", rows=(("LC, smoothed heading", "full"),),
              short="LC smoothed\nhdg", color="#ffbb78"),
    Technique("lc_sim_heading", "oracle", "issue 15",
              "ORACLE: lag correction fed the simulator's heading", lag="pose",
              lag_heading="truth",
              rows=(("Oracle: LC (simulator heading)", "full"),
                    ("Oracle: LC (simulator heading) No Turns", _LC_NO_TURNS)),
              short="ORACLE\nLC sim hdg", color="#ffffff", oracle_of="lc"),
    Technique("lc_sim_heading+dyn", "oracle", "issue 15",
              "ORACLE: lag correction fed the simulator's heading, + Dyn SW", lag="pose",
              lag_heading="truth", dynamic=True,
              rows=(("Oracle: LC (simulator heading) + Dyn SW", "full"),),
              short="ORACLE\nLC sim+Dyn", color="#dddddd", oracle_of="lc+dyn"),
)

_BY_NAME = {t.name: t for t in REGISTRY}
if len(_BY_NAME) != len(REGISTRY):
    raise RuntimeError("technique registry: duplicate names")

#: Names of every technique, in table order (the spec's ``technique`` axis).
TECHNIQUES = tuple(_BY_NAME)
#: Techniques that use the truth (diagnostics, never estimator results).
ORACLE_TECHNIQUES = tuple(t.name for t in REGISTRY if t.oracle)
#: The pose-filter family (issue 14).
FILTER_TECHNIQUES = tuple(t.name for t in REGISTRY if t.method in FILTER_METHODS)
#: Techniques whose solver / weighting axis does not apply (recorded as "-").
NO_SOLVER = tuple(t.name for t in REGISTRY if not t.uses_solver)
NO_WEIGHTS = tuple(t.name for t in REGISTRY if not t.uses_weights)
#: Techniques with the dynamic window (dyn_window, turning and dyn_growth apply).
DYNAMIC = tuple(t.name for t in REGISTRY if t.dynamic)


def oracle_pairs() -> dict[str, str]:
    """The estimated-heading technique -> its oracle (the simulator's heading), from the
    entries' ``oracle_of``."""
    return {t.oracle_of: t.name for t in REGISTRY if t.oracle_of is not None}


def course_pairs() -> dict[str, str]:
    """The as-written lag correction -> its course-based variant, from ``course_of``."""
    return {t.course_of: t.name for t in REGISTRY if t.course_of is not None}


def technique(name: str, plugins: Mapping[str, Technique] | None = None) -> Technique:
    """The registry entry of ``name``, else the plug-in entry ``plugins[name]``
    (:func:`plugin_entries`); ValueError naming the known ones otherwise."""
    try:
        return _BY_NAME[name]
    except (KeyError, TypeError):
        pass
    if plugins and isinstance(name, str) and name in plugins:
        return plugins[name]
    raise ValueError(f"technique: unknown technique {name!r}; allowed: {list(TECHNIQUES)}"
                     + (f", plug-ins {list(plugins)}" if plugins else "")
                     + ", or a plug-in 'package.module:ClassName' (README, Plug-in trackers)")


def is_plugin_name(name: object, tables: Mapping | None = None) -> bool:
    """Whether a ``technique`` value names a plug-in: not a registry name, and an import
    path ("pkg.module:Name") or a name with a ``[techniques."<name>"]`` table. (An
    entry-point name without a table is a plug-in too; :mod:`experiments.spec` checks the
    installed entry points.)"""
    return (isinstance(name, str) and name not in _BY_NAME
            and (":" in name or name in (tables or {})))


def plugin_names(raw: Mapping, extra: Iterable[str] = ()) -> list[str]:
    """The plug-in technique names of a spec's raw table, in the order the spec first
    names them: its ``[techniques]`` tables, then ``technique`` values of ``[defaults]``
    and the grid blocks (import paths), then ``extra`` (e.g. entry-point names, or the
    techniques found in a results table) that are not registry names."""
    tables = raw.get("techniques") if isinstance(raw.get("techniques"), Mapping) else {}
    seen: dict[str, None] = dict.fromkeys(k for k in tables if k not in _BY_NAME)
    blocks = [raw.get("defaults") or {}, *(raw.get("grid") or [])]
    for b in blocks:
        v = b.get("technique") if isinstance(b, Mapping) else None
        for x in v if isinstance(v, list) else [v]:
            if is_plugin_name(x, tables):
                seen.setdefault(x)
    for x in extra:
        if isinstance(x, str) and x not in _BY_NAME:
            seen.setdefault(x)
    return list(seen)


def plugin_label(tracker: str) -> str:
    """The default label of a plug-in: its class name ("pkg.mod:MeanTracker" ->
    "MeanTracker"), or the entry-point name."""
    return tracker.rpartition(":")[2].rpartition(".")[2] if ":" in tracker else tracker


def plugin_entries(raw: Mapping, extra: Iterable[str] = ()) -> dict[str, Technique]:
    """The plug-in entries of a spec's raw table (:func:`plugin_names`): name ->
    :class:`Technique` of kind "plugin". Pure (imports nothing): the spec's loader
    validates the tables and loads the trackers; the outputs rebuild the same entries
    from the results folder's ``spec.toml``."""
    tables = raw.get("techniques") if isinstance(raw.get("techniques"), Mapping) else {}
    out = {}
    for i, name in enumerate(plugin_names(raw, extra)):
        tab = tables.get(name) or {}
        tracker = tab.get("tracker", name)
        label = tab.get("label") or plugin_label(tracker)
        out[name] = Technique(
            name, "plugin", f"plug-in {tracker}", f"plug-in tracker {tracker}",
            method="plugin", rows=((label, "full"),), heading_row=label, short=label,
            color=tab.get("color") or PLUGIN_PALETTE[i % len(PLUGIN_PALETTE)],
            tracker=tracker,
            options=json.dumps(tab.get("options") or {}, sort_keys=True,
                               separators=(",", ":")))
    return out


def table_rows(kind: str) -> dict[str, tuple[str, str]]:
    """Table rows of the techniques of ``kind`` (:data:`KINDS`), in table order:
    label -> (technique, mask)."""
    if kind not in KINDS:
        raise ValueError(f"kind: must be one of {KINDS}, got {kind!r}")
    return {label: (t.name, mask) for t in REGISTRY if t.kind == kind
            for label, mask in t.rows}


def reading_rows() -> dict[str, tuple[str, str, str | None]]:
    """The other readings of the Tables 4.1/4.2 rows: label -> (technique, mask, growth
    rule or None = the faithful one)."""
    return {label: (t.name, mask, rule) for t in REGISTRY for label, mask, rule in t.readings}


def heading_rows() -> dict[str, str]:
    """Rows of the heading table: label -> technique, the pose-filter family first, then
    the window fits it is compared with."""
    listed = [t for t in REGISTRY if t.heading_row]
    ordered = ([t for t in listed if t.method in FILTER_METHODS]
               + [t for t in listed if t.method not in FILTER_METHODS])
    return {t.heading_row: t.name for t in ordered}


def techniques_help() -> str:
    """The technique list of the CLI help: name, kind and summary, one line each."""
    width = max(len(t.name) for t in REGISTRY)
    return "\n".join(f"  {t.name:<{width}}  {t.summary} ({t.source})"
                     + (f" (needs: pip install -e '.[{t.requires[1]}]')" if t.requires else "")
                     for t in REGISTRY)


def plugins_in_results(techniques: Iterable[str], out_dir: Any = None,
                       raw: Mapping | None = None) -> dict[str, Technique]:
    """The plug-in entries of a results table's ``techniques`` (names not in the registry):
    built from the spec's raw table ``raw``, else from ``<out_dir>/spec.toml`` (the spec as
    the sweep ran it), else from the names alone (default labels and colours)."""
    names = [t for t in dict.fromkeys(techniques) if isinstance(t, str) and t not in _BY_NAME]
    if not names:
        return {}
    if raw is None and out_dir is not None:
        import tomllib
        from pathlib import Path

        try:
            raw = tomllib.loads((Path(out_dir) / "spec.toml").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raw = None
    return plugin_entries(raw or {}, names)
