"""Declarative experiment specs: TOML files validated on load, expanded into a grid of cells.

A spec names *what* to run (paths, sensor configurations, noise models, seeds, window sizes,
weighting schemes, techniques, solvers, evaluation masks, the page's extra replay, the
report's sensitivity study); the sweep (:mod:`experiments.sweep`) runs it. The format, every
axis and the path rule for the files a spec names are in ``docs/spec-format.md``. Every key
is validated: unknown keys and bad values raise :class:`SpecError` naming the field
(``grid[1].window[2]: must be a positive integer, got 0``). One declaration per axis
(:data:`AXIS_SCHEMA`) gives the Cell type, the validation and the expansion; a cell's key
hashes its axes, seeds and the contents of the files it names (GPS dissertation
000_8f82f8df647bf685.txt, Sections 4.9-4.12: the axes of its moving-platform study).
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, make_dataclass, replace
from operator import attrgetter
from pathlib import Path
from typing import Any

from estimator.metrics import MASKS
from estimator.model_files import MODELS_DIR as MODELS
from estimator.model_files import PROJECT_DIR, SOURCE_CHECKOUT, parse_toml, resolve_model_file
from estimator.track_options import GROWTH_RULES
from estimator.weights import WEIGHTINGS as WEIGHT_SCHEMES
from estimator.weights import Weighting
from estimator.window import SOLVERS
from experiments.techniques import (
    FILTER_TECHNIQUES,
    NO_SOLVER,
    NO_WEIGHTS,
    ORACLE_TECHNIQUES,
    PLUGIN_KEYS,
    REGISTRY,
    TECHNIQUES,
    TURNING_SOURCES,
    Technique,
    plugin_entries,
    techniques_help,
)
from experiments.techniques import technique as _technique

__all__ = ["AXES", "DEFAULT_MASKS", "DYN_GROWTH", "FILTER_TECHNIQUES", "FLIGHT_FILE", "MASKS",
           "NO_SOLVER", "NO_WEIGHTS", "ORACLE_TECHNIQUES", "PRESETS_DIR", "SOLVERS", "TECHNIQUES",
           "WEIGHTINGS", "Cell", "Spec", "SpecError", "available_presets", "axis_help",
           "flight_folder", "load_spec", "sensitivity_folder"]

REPO = Path(__file__).resolve().parents[1]
#: Where results/ lives: the checkout's, or the working directory's for an installed wheel.
RESULTS_ROOT = (REPO if SOURCE_CHECKOUT else Path.cwd()) / "results"
PRESETS_DIR = Path(__file__).resolve().parent / "presets"

#: Weightings, solvers, masks and growth rules are the estimators' vocabularies
#: (estimator.weights, estimator.window, estimator.metrics, estimator.track_options);
#: techniques, their applicable axes and the turning sources come from the technique
#: registry (experiments.techniques). A weighting may carry a Huff threshold in metres,
#: "huff:<t>" (4.8.2 uses 3.5): :meth:`estimator.weights.Weighting.parse`.
WEIGHTINGS = WEIGHT_SCHEMES
#: Masks of a spec that does not name any.
DEFAULT_MASKS = ("full", "no_turns")
TURNING = TURNING_SOURCES
DYN_GROWTH = GROWTH_RULES

#: Validation limits (checked on load, before anything is allocated or simulated).
#: A window longer than this many epochs is no sliding window (Path 2 has ~4000 epochs).
MAX_WINDOW = 100_000
#: A synthesized stationary session longer than 7 days (the NMEA importer's grid limit too)
#: would only allocate memory: the dissertation's recording lasted ~4000 s (Section 4.1.1).
MAX_SESSION_S = 7 * 86400.0
#: Seeds per spec and cells per spec: a grid above this is a typo, not an experiment
#: (the thesis preset has 780 cells; expanding 1e6 cells alone takes about a minute).
MAX_SEEDS = 10_000
MAX_CELLS = 200_000
_TOP = {"name", "description", "seed", "seeds", "masks", "sim_seed", "session_s", "defaults",
        "grid", "epochs", "techniques", "page", "report"}
#: The file of a flight replay source (``[page] flight``; ``python -m experiments.ultrasonic``).
FLIGHT_FILE = "flight_series.csv"
#: The file that marks a sensitivity study's folder (``[report] sensitivity``; ``python -m
#: experiments.sensitivity``).
SENSITIVITY_FILE = "sensitivity.csv"


class SpecError(ValueError):
    """A spec is invalid; the message names the file and the offending field."""


# --------------------------------------------------------------------------- resources
def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _resolve(kind: str | None, value: str, base: Path | None, where: str) -> Path:
    """A file the spec names: ``models/<kind>/<name>.toml`` for a bare name, else a path
    under the one rule of :func:`estimator.model_files.resolve_model_file` (relative to the
    spec's folder, then the project; never outside them). ``kind`` None: no bare names (a
    ``session:`` file)."""
    return resolve_model_file(value, None if kind is None else MODELS / kind, where,
                              base=base, error=SpecError)


def _session_file(value: str, base: Path | None, where: str) -> Path:
    """The file of a ``session:<file>`` noise, under the same rule as every other file."""
    return _resolve(None, value[len("session:"):], base, where)


def _is_file_value(value: str) -> bool:
    p = Path(value)
    return bool(p.suffix) or p.parent != Path(".")


def _file_label(path: str) -> str:
    """The label of a model file given by path: its ``name`` field (as the tables show it,
    issue 13; a path file's name is its stem), else the file's stem, never ``.toml``."""
    try:
        name = parse_toml(Path(path).read_bytes(), path, error=SpecError).get("name")
    except (OSError, SpecError):
        name = None
    return name if isinstance(name, str) and name else Path(path).stem


def _resolve_recording(value: str, base: Path | None, where: str) -> Path:
    """A recording name in ``models/recordings/`` or a ``.toml`` file (relative to the spec)."""
    return _resolve("recordings", value, base, where)


def _check_session_overrides(ov: dict, where: str) -> None:
    """noise_overrides of a ``session:`` noise: the replay keys of :func:`sim.gps.observe`."""
    from sim.gps import REPLAY_MODES, SESSION_REPLAY_KEYS, GpsModelError, GpsNoiseModel

    mode = ov.get("replay", "by_receiver")
    if mode not in REPLAY_MODES:
        raise SpecError(f"{where}.replay: unknown mode {mode!r}; allowed: {list(REPLAY_MODES)}")
    rest = sorted(set(ov) - set(SESSION_REPLAY_KEYS))
    if mode == "common_plus_model":
        if not isinstance(ov.get("model"), str):
            raise SpecError(f"{where}.model: mode 'common_plus_model' needs a noise-model name")
        if _is_file_value(ov["model"]):
            # the replay loads the model by name at run time: a file here would escape the
            # spec's path rule (and its hash); models live in models/noise/
            raise SpecError(f"{where}.model: must be a noise-model name in models/noise/, got "
                            f"the file path {ov['model']!r}")
        try:
            GpsNoiseModel.load(ov["model"]).with_overrides(**{k: ov[k] for k in rest})
        except (GpsModelError, TypeError, ValueError) as exc:
            raise SpecError(f"{where}: {exc}") from None
    elif rest or "model" in ov:
        raise SpecError(f"{where}: {rest or ['model']} do not apply to replay mode {mode!r} "
                        f"(keys {list(SESSION_REPLAY_KEYS)})")
    if mode == "by_receiver" and ("receiver" in ov or "shift_s" in ov):
        raise SpecError(f"{where}: receiver / shift_s apply to the one-receiver modes only")
    if "shift_s" in ov and (mode != "shifted" or isinstance(ov["shift_s"], bool)
                            or not isinstance(ov["shift_s"], (int, float))
                            or not 0 < ov["shift_s"] < float("inf")):
        raise SpecError(f"{where}.shift_s: a positive number of seconds with mode 'shifted', "
                        f"got {ov['shift_s']!r}")


# --------------------------------------------------------------------------- axes
def _canon(d: dict) -> str:
    return json.dumps(d, sort_keys=True, separators=(",", ":"))


def _check_table(axis: str, forbidden: tuple[str, ...] = ()) -> Callable:
    """A table-valued axis (``path_overrides``, ``noise_overrides``): field = value pairs
    of TOML scalars or lists; ``forbidden`` fields cannot be overridden."""
    def check(v: object, where: str, base: Path | None, plugins: dict | None) -> dict:
        if not isinstance(v, dict):
            raise SpecError(f"{where}: must be a table of field = value, got {v!r}")
        for k, x in v.items():
            if not isinstance(x, (int, float, str, bool, list)):
                raise SpecError(f"{where}.{k}: unsupported value {x!r}")
        bad = sorted(set(v) & set(forbidden))
        if bad:
            raise SpecError(f"{where}: {bad} cannot be overridden (add a path file instead)")
        return dict(v)
    return check


def _check_epochs_count(v: object, where: str, base: Path | None, plugins: dict | None) -> int:
    """A number of epochs (``window``, ``dyn_window``): an integer in [1, MAX_WINDOW]."""
    if not _is_int(v) or not 1 <= v <= MAX_WINDOW:
        raise SpecError(f"{where}: must be a positive integer, got {v!r} "
                        f"(at most {MAX_WINDOW} epochs)")
    return int(v)


def _named(check: Callable[[str, str, Path | None, dict | None], None]) -> Callable:
    """A name-valued axis: a non-empty string, then ``check``."""
    def named(v: object, where: str, base: Path | None, plugins: dict | None) -> str:
        if not isinstance(v, str) or not v:
            raise SpecError(f"{where}: must be a non-empty string, got {v!r}")
        check(v, where, base, plugins)
        return v
    return named


def _weighting(v: str, where: str, base: Path | None, plugins: dict | None) -> None:
    try:
        Weighting.parse(v)
    except ValueError as exc:
        raise SpecError(f"{where}: {str(exc).removeprefix('weighting: ')}") from None


def _technique_value(v: str, where: str, base: Path | None, plugins: dict | None) -> None:
    """A registry technique or one of the spec's plug-ins; an optional dependency present."""
    try:
        tech = _technique(v, plugins)
    except ValueError as exc:
        raise SpecError(f"{where}: {str(exc).removeprefix('technique: ')}") from None
    if tech.requires:
        import importlib.util

        module, extra = tech.requires
        if importlib.util.find_spec(module) is None:
            raise SpecError(f"{where}: technique {v!r} needs the optional dependency "
                            f"{module}: pip install -e '.[{extra}]'")


def _choice(what: str, allowed: tuple[str, ...]) -> Callable:
    """A value of a vocabulary (``allowed``), e.g. the solvers."""
    def check(v: str, where: str, base: Path | None, plugins: dict | None) -> None:
        if v not in allowed:
            raise SpecError(f"{where}: unknown {what} {v!r}; allowed: {list(allowed)}")
    return check


def _model_file(kind: str) -> Callable:
    """A model file of ``models/<kind>/`` or a path (the one path rule, :func:`_resolve`)."""
    def check(v: str, where: str, base: Path | None, plugins: dict | None) -> None:
        _resolve(kind, v, base, where)
    return check


def _noise_value(v: str, where: str, base: Path | None, plugins: dict | None) -> None:
    """"none", ``session:<file>`` or a noise model (name or file)."""
    if v.startswith("session:"):
        _session_file(v, base, where)
    elif v != "none":
        _resolve("noise", v, base, where)


def _recording_value(v: str, where: str, base: Path | None, plugins: dict | None) -> None:
    if v != "-":
        _resolve_recording(v, base, where)


#: Whether an axis applies to a technique entry (:attr:`Axis.applies`).
_uses_solver, _uses_weights = attrgetter("uses_solver"), attrgetter("uses_weights")
_dynamic = attrgetter("dynamic")


@dataclass(frozen=True)
class Axis:
    """One spec axis, declared once: the Cell's field, the validation of its values and the
    grid's expansion derive from :data:`AXIS_SCHEMA`.

    name : the key in ``[defaults]`` and grid blocks, the Cell field, the cells.parquet
    column. kind : ``int``, ``str`` or ``dict`` (a table; canonical JSON in the Cell).
    default : its value where neither ``[defaults]`` nor a block sets it (None: required,
    checked by :meth:`Spec.from_dict`). check : ``(value, where, base, plugins) ->
    canonical value``, a :class:`SpecError` naming ``where`` otherwise. applies : for an
    axis that applies per technique, whether it applies to a technique entry (None:
    always). unset : the Cell's value where it does not apply. keyed_unset : whether the
    cell key includes the axis when it is ``unset`` (``recording``: no, so the keys of
    simulated cells are those from before the axis existed).
    """

    name: str
    kind: type
    default: Any
    check: Callable[[Any, str, Path | None, dict | None], Any]
    applies: Callable[[Technique], bool] | None = None
    unset: Any = None
    keyed_unset: bool = True

    def cell_value(self, v: Any) -> Any:
        """The Cell's (hashable) value of a checked value ``v``."""
        return _canon(v) if self.kind is dict else self.kind(v)


#: Every axis, in the order of the cell's columns (cells.parquet, Cell.params).
AXIS_SCHEMA: tuple[Axis, ...] = (
    Axis("path", str, None, _named(_model_file("paths"))),
    Axis("config", str, "rover_gps8", _named(_model_file("configs"))),
    Axis("noise", str, "gps_stationary", _named(_noise_value)),
    Axis("noise_overrides", dict, {}, _check_table("noise_overrides"), unset={}),
    Axis("path_overrides", dict, {}, _check_table("path_overrides", ("name", "waypoints")),
         unset={}),
    Axis("window", int, None, _check_epochs_count),
    Axis("weighting", str, "none", _named(_weighting), _uses_weights, "-"),
    Axis("technique", str, "none", _named(_technique_value)),
    Axis("solver", str, "procrustes", _named(_choice("solver", SOLVERS)), _uses_solver, "-"),
    Axis("dyn_window", int, 1, _check_epochs_count, _dynamic, 0),
    Axis("turning", str, "controller", _named(_choice("turning source", TURNING)), _dynamic,
         "-"),
    Axis("recording", str, "-", _named(_recording_value), unset="-", keyed_unset=False),
    Axis("dyn_growth", str, "jump", _named(_choice("growth rule", DYN_GROWTH)), _dynamic, "-"),
)
_BY_AXIS = {a.name: a for a in AXIS_SCHEMA}
#: Every axis and its default when neither [defaults] nor a grid block sets it.
AXES: dict[str, Any] = {a.name: a.default for a in AXIS_SCHEMA}
#: The nesting of the grid's product (outermost first): the schema's order with
#: path_overrides beside path, so cells come in the order they always did.
_PRODUCT_ORDER = ("path", "path_overrides",
                  *(a.name for a in AXIS_SCHEMA if a.name not in ("path", "path_overrides")))
_DICT_AXES = tuple(a.name for a in AXIS_SCHEMA if a.kind is dict)


# --------------------------------------------------------------------------- cells
class _CellMethods:
    """One point of the grid: a full set of axis values plus a seed.

    The axis fields come from :data:`AXIS_SCHEMA` (a value that does not apply to the
    cell's technique is the axis's ``unset``, e.g. "-" or 0; tables are canonical JSON).
    ``key`` is a stable hash of everything that determines the cell's numbers (axis values,
    seed, spec seed, simulator seed, the contents of the files it names, and a plug-in's
    options and source).
    """

    @property
    def entry(self) -> Technique:
        """The technique's entry: the registry's, or the spec's plug-in entry."""
        return self.plugin if self.plugin is not None else _technique(self.technique)

    def params(self) -> dict[str, Any]:
        """Axis values and seed as a flat dict (the cell's columns in cells.parquet)."""
        return {**{a.name: getattr(self, a.name) for a in AXIS_SCHEMA}, "seed": self.seed}

    def file(self, kind: str) -> str | None:
        """Resolved file for ``kind`` in {"path", "config", "noise", "recording"} (None when
        the cell has none, e.g. noise "none")."""
        return dict(self.files).get(kind)

    @property
    def truth_key(self) -> tuple:
        """Cells sharing this key share one simulated Truth (or one loaded recording)."""
        if self.recording != "-":
            return ("recording", self.file("recording"))
        return (self.file("path"), self.path_overrides, self.file("config"))

    @property
    def noise_key(self) -> tuple:
        """Cells sharing this key share one set of noisy observations."""
        return (*self.truth_key, self.file("noise"), self.noise, self.noise_overrides, self.seed)



#: The Cell type: the axis fields of :data:`AXIS_SCHEMA`, the seed, and the cell's identity
#: (``key``), files and plug-in entry (not compared).
Cell = make_dataclass(
    "Cell",
    [*((a.name, a.kind if a.kind is not dict else str,
        field(default=a.cell_value(a.unset) if a.unset is not None else None))
       for a in AXIS_SCHEMA),
     ("seed", int, field(default=0)),
     ("key", str, field(default="", compare=False)),
     ("files", tuple, field(default=(), compare=False, repr=False)),
     ("plugin", Technique | None, field(default=None, compare=False, repr=False))],
    bases=(_CellMethods,), frozen=True)
Cell.__module__, Cell.__doc__ = __name__, _CellMethods.__doc__   # pickled by this name


def _cell_labels(v: dict, files: dict, seen: dict, where: str) -> dict[str, str]:
    """The labels of a combination's path / config / noise: a name is itself, a file given
    by path its model's name (:func:`_file_label`), a ``session:`` file ``session:<stem>``.
    Two files with one label on one axis would merge in the tables: an error naming both."""
    out = {}
    for axis in ("path", "config", "noise"):
        val = v[axis]
        f = files.get(axis, (val,))[0]
        if axis == "noise" and val.startswith("session:"):
            lab = "session:" + Path(f).stem
        elif _is_file_value(val) and axis in files:
            lab = _file_label(f)
        else:
            lab = val
        out[axis] = lab
        prev = seen.setdefault((axis, lab), f)
        if prev != f:
            raise SpecError(f"{where}.{axis}: {val!r} ({f}) and {prev} would both be labelled "
                            f"{lab!r}; rename one of the files")
    return out


# --------------------------------------------------------------------------- spec
@dataclass(frozen=True)
class Spec:
    """A validated experiment spec (see the module docstring for the TOML format)."""

    name: str
    description: str
    seed: int
    seeds: tuple[int, ...]
    masks: tuple[str, ...]
    sim_seed: int
    defaults: dict
    grid: tuple[dict, ...]
    epochs: dict | None
    session_s: float = 4000.0
    source: str = "<dict>"
    base_dir: Path = REPO
    raw: dict = field(default_factory=dict, repr=False)
    #: Built in Python without ``base_dir``: file paths are the caller's, taken as given.
    direct_paths: bool = False
    #: Plug-in techniques: name -> entry (kind "plugin", experiments.techniques).
    plugins: dict = field(default_factory=dict, repr=False)
    #: Plug-in techniques: name -> (source file of the tracker class, its sha256 prefix).
    plugin_files: dict = field(default_factory=dict, repr=False)
    #: The ``[page]`` table (``flight``: the flight replay's source folder), or None.
    page: dict | None = None
    #: The ``[report]`` table (``sensitivity``: the sensitivity study's folder the Cause
    #: lines quote), or None.
    report: dict | None = None

    @property
    def _base(self) -> Path | None:
        """The folder files are named relative to, None for direct paths (``_resolve``)."""
        return None if self.direct_paths else self.base_dir

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_dict(cls, data: dict, *, source: str = "<dict>", base_dir: Path | None = None
                  ) -> Spec:
        """Validate ``data`` (the TOML table) and build a Spec; errors name the field."""
        base = Path(base_dir) if base_dir is not None else REPO
        # a spec built in Python without a folder names files directly (the caller's own
        # paths); one read from a file names them under the rule for files in files
        rbase = None if base_dir is None else base
        src = source
        if not isinstance(data, dict):
            raise SpecError(f"{src}: expected a table")
        unknown = sorted(set(data) - _TOP)
        if unknown:
            raise SpecError(f"{src}: unknown key(s) {unknown}; allowed: {sorted(_TOP)}")
        name = data.get("name")
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_.\-]+", name or ""):
            raise SpecError(f"{src}: name: required, letters/digits/._- only, got {name!r}")
        desc = data.get("description", "")
        if not isinstance(desc, str):
            raise SpecError(f"{src}: description: must be a string, got {desc!r}")
        seed = data.get("seed", 0)
        if not _is_int(seed) or seed < 0:
            raise SpecError(f"{src}: seed: must be a non-negative integer, got {seed!r}")
        sim_seed = data.get("sim_seed", 0)
        if not _is_int(sim_seed) or sim_seed < 0:
            raise SpecError(f"{src}: sim_seed: must be a non-negative integer, got {sim_seed!r}")
        session_s = data.get("session_s", 4000.0)
        if (not isinstance(session_s, (int, float)) or isinstance(session_s, bool)
                or not 0 < session_s <= MAX_SESSION_S):
            raise SpecError(f"{src}: session_s: must be a number of seconds in "
                            f"(0, {MAX_SESSION_S:.0f}] (7 days), got {session_s!r}")
        seeds_raw = data.get("seeds", 1)
        if _is_int(seeds_raw):
            if not 1 <= seeds_raw <= MAX_SEEDS:
                raise SpecError(f"{src}: seeds: count must be in [1, {MAX_SEEDS}], "
                                f"got {seeds_raw!r}")
            seeds = tuple(range(seeds_raw))
        elif isinstance(seeds_raw, list) and 0 < len(seeds_raw) <= MAX_SEEDS:
            for i, s in enumerate(seeds_raw):
                if not _is_int(s) or s < 0:
                    raise SpecError(f"{src}: seeds[{i}]: must be a non-negative integer, got {s!r}")
            if len(set(seeds_raw)) != len(seeds_raw):
                raise SpecError(f"{src}: seeds: duplicate values in {seeds_raw!r}")
            seeds = tuple(int(s) for s in seeds_raw)
        else:
            raise SpecError(f"{src}: seeds: must be a count in [1, {MAX_SEEDS}] or a list of "
                            f"1 to {MAX_SEEDS} integers, got {seeds_raw!r}"[:300])
        masks_raw = data.get("masks", list(DEFAULT_MASKS))
        masks = tuple(_as_list(masks_raw, f"{src}: masks"))
        for i, mk in enumerate(masks):
            if mk not in MASKS:
                raise SpecError(f"{src}: masks[{i}]: unknown mask {mk!r}; allowed: {list(MASKS)}")
        if len(set(masks)) != len(masks) or not masks:
            raise SpecError(f"{src}: masks: must be non-empty without duplicates, got {masks!r}")

        plugins, plugin_files = _load_plugins(data, src)
        defaults = data.get("defaults", {})
        if not isinstance(defaults, dict):
            raise SpecError(f"{src}: defaults: must be a table")
        defaults = {k: _check_axis(k, v, f"{src}: defaults.{k}", rbase, scalar=True,
                                   plugins=plugins)
                    for k, v in defaults.items()}
        grid_raw = data.get("grid")
        if not isinstance(grid_raw, list) or not grid_raw:
            raise SpecError(f"{src}: grid: at least one [[grid]] block is required")
        grid = []
        for gi, block in enumerate(grid_raw):
            where = f"{src}: grid[{gi}]"
            if not isinstance(block, dict):
                raise SpecError(f"{where}: must be a table")
            out: dict[str, Any] = {"name": block.get("name", f"grid{gi}")}
            if not isinstance(out["name"], str):
                raise SpecError(f"{where}.name: must be a string, got {out['name']!r}")
            for k, v in block.items():
                if k == "name":
                    continue
                vals = v if (isinstance(v, list)) else [v]
                if not vals:
                    raise SpecError(f"{where}.{k}: empty list")
                out[k] = [_check_axis(k, x, f"{where}.{k}" + (f"[{i}]" if isinstance(v, list)
                                                               else ""), rbase, scalar=True,
                                      plugins=plugins)
                          for i, x in enumerate(vals)]
            has_rec = any(r != "-" for r in out.get("recording", [defaults.get("recording", "-")]))
            for req in ("path", "window"):
                if req == "path" and has_rec:
                    continue       # a recording replaces the path (spec docstring)
                if req not in out and req not in defaults:
                    raise SpecError(f"{where}.{req}: required (in the block or in [defaults])")
            grid.append(out)
        epochs = data.get("epochs")
        if epochs is not None:
            epochs = _check_epochs(epochs, f"{src}: epochs", rbase, plugins)
        page = data.get("page")
        if page is not None:
            page = _check_page(page, f"{src}: page", rbase)
        report = data.get("report")
        if report is not None:
            report = _check_report(report, f"{src}: report", rbase)
        n_grid = sum(math.prod(len(b[k]) for k in b if k != "name") for b in grid)
        if n_grid * len(seeds) > MAX_CELLS:
            raise SpecError(f"{src}: grid: {n_grid} axis combinations x {len(seeds)} seeds = "
                            f"{n_grid * len(seeds)} cells, more than {MAX_CELLS}; split the spec")
        spec = cls(name=name, description=desc, seed=int(seed), seeds=seeds, masks=masks,
                   sim_seed=int(sim_seed), defaults=defaults, grid=tuple(grid), epochs=epochs,
                   session_s=float(session_s), source=src, base_dir=base, raw=data,
                   direct_paths=base_dir is None, plugins=plugins, plugin_files=plugin_files,
                   page=page, report=report)
        spec.expand()   # resolve and check every file now, so bad names fail at load time
        return spec

    # ---------------------------------------------------------------- grid
    def expand(self) -> list[Cell]:
        """All cells of the spec (union of the grid blocks, duplicates removed, stable order)."""
        cells: dict[str, Cell] = {}
        hashes: dict[tuple[str, str], str] = {}
        checked: set = set()
        labels: dict[tuple[str, str], str] = {}
        for gi, block in enumerate(self.grid):
            axes = {k: block.get(k, [self.defaults[k]] if k in self.defaults else [AXES[k]])
                    for k in _PRODUCT_ORDER}
            for combo in itertools.product(*axes.values()):
                v = dict(zip(axes, combo))
                if v["recording"] != "-":
                    for key in ("path", "noise", "path_overrides"):
                        if key in block:
                            raise SpecError(f"{self.source}: grid[{gi}].{key}: does not apply "
                                            f"to a block with a recording (the recording "
                                            f"replaces path and noise)")
                    self._recording_axes(v, "config" in block, hashes,
                                         f"{self.source}: grid[{gi}]")
                tech = v["technique"]
                entry = _technique(tech, self.plugins)
                for a in AXIS_SCHEMA:           # axes that do not apply: their unset value
                    if a.applies is not None and not a.applies(entry):
                        v[a.name] = a.unset
                if entry.dynamic and v["dyn_window"] > v["window"]:
                    raise SpecError(f"{self.source}: grid[{gi}].dyn_window: {v['dyn_window']} "
                                    f"exceeds window {v['window']} (the small window of the "
                                    "dynamic technique must be <= the window)")
                files = self._files(v, hashes, f"{self.source}: grid[{gi}]")
                plugin = self.plugins.get(tech)
                if plugin is not None:
                    files["tracker"] = self.plugin_files[tech]
                self._check_overrides(v, files, checked, f"{self.source}: grid[{gi}]")
                lab = _cell_labels(v, files, labels, f"{self.source}: grid[{gi}]")
                values = {a.name: a.cell_value({**v, **lab}[a.name]) for a in AXIS_SCHEMA}
                for seed in self.seeds:
                    cell = Cell(**values, seed=int(seed), plugin=plugin,
                                files=tuple(sorted((k, p) for k, (p, _) in files.items())))
                    params = cell.params()
                    for a in AXIS_SCHEMA:           # (recording: keys as before the axis)
                        if not a.keyed_unset and params[a.name] == a.cell_value(a.unset):
                            del params[a.name]
                    ident = {"v": 1, "spec_seed": self.seed, "sim_seed": self.sim_seed,
                             "session_s": self.session_s,
                             **params,
                             "files": {k: h for k, (_, h) in sorted(files.items())}}
                    if plugin is not None:          # built-in cells' keys as before
                        ident["plugin"] = {"tracker": plugin.tracker,
                                           "options": json.loads(plugin.options)}
                    key = hashlib.sha256(_canon(ident).encode()).hexdigest()[:20]
                    cells.setdefault(key, replace(cell, key=key))
        return list(cells.values())

    @staticmethod
    def _check_overrides(v: dict, files: dict, checked: set, where: str) -> None:
        """Apply path / noise overrides once per combination so bad fields fail at load."""
        if v["recording"] != "-":
            return             # checked by _recording_axes: no overrides on recordings
        if v["path_overrides"]:
            from sim.paths import Path as SimPath
            from sim.paths import load_path

            def overridden_path() -> None:
                d = {**load_path(files["path"][0]).to_dict(), **v["path_overrides"]}
                SimPath.from_dict(d, source="path_overrides")

            _once(checked, ("path", files["path"][0], _canon(v["path_overrides"])),
                  f"{where}.path_overrides", overridden_path)
        if v["noise_overrides"] and v["noise"].startswith("session:"):
            _check_session_overrides(v["noise_overrides"], f"{where}.noise_overrides")
        elif v["noise_overrides"]:
            if "noise" not in files:
                raise SpecError(f"{where}.noise_overrides: only applies to a noise model or "
                                f"a session, not to noise {v['noise']!r}")
            from sim.gps import GpsNoiseModel

            _once(checked, ("noise", files["noise"][0], _canon(v["noise_overrides"])),
                  f"{where}.noise_overrides", lambda: GpsNoiseModel.load(
                      files["noise"][0]).with_overrides(**v["noise_overrides"]))

    def _recording_axes(self, v: dict, explicit_config: bool, hashes: dict, where: str) -> None:
        """Fill a recording cell's axes (spec docstring): path / noise labels, no
        overrides, the recording's configuration unless the block names one."""
        from sim.recording import recording_digest, recording_summary

        if v["path_overrides"]:
            raise SpecError(f"{where}: path_overrides do not apply to recording "
                            f"{v['recording']!r}")
        rfile = _resolve_recording(v["recording"], self._base, f"{where}.recording")
        k = ("recordings", str(rfile))
        try:
            if k not in hashes:
                hashes[k] = recording_digest(rfile)
            summary = recording_summary(rfile)
        except (ValueError, TypeError) as exc:      # RecordingError, ConfigError, ...
            raise SpecError(f"{where}.recording: {exc}") from None
        v["_recording_file"] = (str(rfile), hashes[k])
        v["path"] = f"recording-{Path(v['recording']).stem}"
        mode = summary["replay_mode"]
        if v["noise_overrides"]:
            if mode is None:
                raise SpecError(f"{where}.noise_overrides: recording {v['recording']!r} has "
                                f"measured observations (no [replay] to override)")
            _check_session_overrides(v["noise_overrides"], f"{where}.noise_overrides")
            mode = v["noise_overrides"].get("replay", "by_receiver")
        v["noise"] = "recording" if mode is None else f"replay:{mode}"
        if not explicit_config:
            v["config"] = summary["config_name"]
            v["_config_file"] = summary["config_file"]

    def _files(self, v: dict, hashes: dict, where: str) -> dict[str, tuple[str, str]]:
        out: dict[str, tuple[str, str]] = {}
        if v["recording"] != "-":
            out["recording"] = v["_recording_file"]
            cpath = Path(v["_config_file"]) if "_config_file" in v else \
                _resolve("configs", v["config"], self._base, f"{where}.config")
            k = ("configs", str(cpath))
            if k not in hashes:
                hashes[k] = _sha(cpath)
            out["config"] = (str(cpath), hashes[k])
            return out
        for kind, axis in (("paths", "path"), ("configs", "config"), ("noise", "noise")):
            val = v[axis]
            if axis == "noise" and val == "none":
                continue
            if axis == "noise" and val.startswith("session:"):
                path = _session_file(val, self._base, f"{where}.noise")
            else:
                path = _resolve(kind, val, self._base, f"{where}.{axis}")
            k = (kind, str(path))
            if k not in hashes:
                if axis != "noise" or not val.startswith("session:"):
                    _check_kind(kind, path, f"{where}.{axis}", val)
                hashes[k] = _sha(path)
            out[axis] = (str(path), hashes[k])
        return out

    def epochs_wanted(self, cell: Cell) -> bool:
        """Whether the spec asks for this cell's per-epoch estimates."""
        if not self.epochs:
            return False
        seeds = self.epochs.get("seeds", "all")
        if seeds != "all" and cell.seed not in seeds:
            return False
        params = cell.params()
        for k, vals in self.epochs.get("where", {}).items():
            pv = params[k]
            if k in _DICT_AXES:
                vals = [_canon(x) for x in vals]
            if pv not in vals:
                return False
        return True

    def with_solver(self, solver: str) -> Spec:
        """The same spec with every cell's solver replaced (CLI ``--solver``).

        The name gets a ``-<solver>`` suffix so the results land beside, not over, the
        default-solver run.
        """
        if solver not in SOLVERS:
            raise SpecError(f"solver: unknown solver {solver!r}; allowed: {list(SOLVERS)}")
        grid = tuple({**b, "solver": [solver]} for b in self.grid)
        raw = copy.deepcopy(self.raw)
        raw["name"] = f"{self.name}-{solver}"
        raw.setdefault("defaults", {})["solver"] = solver
        for b in raw.get("grid", []):
            b["solver"] = solver
        return replace(self, name=raw["name"], grid=grid, raw=raw,
                       defaults={**self.defaults, "solver": solver})

    def with_seeds(self, seeds: Iterable[int]) -> Spec:
        """The same spec with another seed list (CLI ``--seeds``)."""
        seeds = tuple(int(s) for s in seeds)
        if not seeds or any(s < 0 for s in seeds):
            raise SpecError(f"seeds: must be non-negative integers, got {seeds!r}")
        raw = {**copy.deepcopy(self.raw), "seeds": list(seeds)}
        return replace(self, seeds=seeds, raw=raw)

    def to_dict(self) -> dict:
        """The validated spec as plain data (written to the results manifest)."""
        return {"name": self.name, "description": self.description, "seed": self.seed,
                "seeds": list(self.seeds), "masks": list(self.masks), "sim_seed": self.sim_seed,
                "session_s": self.session_s,
                "defaults": self.defaults, "grid": [dict(b) for b in self.grid],
                "epochs": self.epochs, "source": self.source,
                **({"techniques": self.raw.get("techniques", {})} if self.plugins else {}),
                **({"page": self.page} if self.page else {}),
                **({"report": self.report} if self.report else {})}


# --------------------------------------------------------------------------- validation
def _check_kind(kind: str, path: Path, where: str, value: str) -> None:
    """The file must load as what the axis names: a path file as ``path``, a sensor
    configuration as ``config``, a GPS noise model as ``noise`` (a configuration given as
    a path, or any other file, fails here and not in the middle of a run)."""
    try:
        if kind == "paths":
            from sim.paths import load_path

            load_path(path)
        elif kind == "configs":
            from estimator.configuration import SensorConfig

            SensorConfig.load(path)
        else:
            from sim.gps import GpsNoiseModel

            GpsNoiseModel.load(path)
    except (ValueError, TypeError, OSError, UnicodeDecodeError) as exc:
        what = {"paths": "path file", "configs": "sensor configuration",
                "noise": "GPS noise model"}[kind]
        raise SpecError(f"{where}: {value!r} is not a {what}: {exc}") from None


def _once(checked: set, key: tuple, where: str, check: Callable[[], object]) -> None:
    """Run ``check`` once per ``key`` (a file and its overrides); its ValueError or TypeError
    becomes a :class:`SpecError` naming ``where``."""
    if key not in checked:
        try:
            check()
        except (ValueError, TypeError) as exc:
            raise SpecError(f"{where}: {exc}") from None
        checked.add(key)


def _is_int(v: object) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _as_list(v: object, where: str) -> list:
    if isinstance(v, str):
        return [v]
    if isinstance(v, list):
        return v
    raise SpecError(f"{where}: must be a string or a list of strings, got {v!r}")


def axis_help() -> str:
    """The values of the spec axes that take a name, for the sweep's ``--help``: every
    technique (from the registry) and the estimators' vocabularies."""
    return "\n".join([
        "techniques (the technique axis):", techniques_help(),
        (f"weightings: {', '.join(WEIGHT_SCHEMES)}; 'huff:<m>' / 'huff_huber:<m>' adds a Huff "
         "threshold in metres"),
        (f"solvers: {', '.join(SOLVERS)};  masks: {', '.join(MASKS)} (default "
         f"{', '.join(DEFAULT_MASKS)});  turning: {', '.join(TURNING)};  dyn_growth: "
         f"{', '.join(DYN_GROWTH)}")])


def _check_axis(axis: str, v: object, where: str, base: Path, *, scalar: bool,
                plugins: dict | None = None) -> Any:
    """Validate one value of an axis by its declaration (:data:`AXIS_SCHEMA`; ``plugins``:
    the spec's plug-in entries, which the ``technique`` axis may name); returns the
    canonical value."""
    if axis not in _BY_AXIS:
        raise SpecError(f"{where.rsplit('.', 1)[0]}: unknown key {axis!r}; allowed axes: "
                        f"{sorted(AXES)} (plus 'name' in a grid block)")
    return _BY_AXIS[axis].check(v, where, base, plugins)


def _check_epochs(e: object, where: str, base: Path, plugins: dict | None = None) -> dict:
    if not isinstance(e, dict):
        raise SpecError(f"{where}: must be a table")
    unknown = sorted(set(e) - {"seeds", "where"})
    if unknown:
        raise SpecError(f"{where}: unknown key(s) {unknown}; allowed: ['seeds', 'where']")
    out: dict[str, Any] = {}
    seeds = e.get("seeds", "all")
    if seeds != "all" and (not isinstance(seeds, list)
                           or not all(_is_int(s) and s >= 0 for s in seeds)):
        raise SpecError(f"{where}.seeds: must be \"all\" or a list of seed values, "
                            f"got {seeds!r}")
    out["seeds"] = seeds
    w = e.get("where", {})
    if not isinstance(w, dict):
        raise SpecError(f"{where}.where: must be a table of axis = [values]")
    out["where"] = {}
    for k, vals in w.items():
        if k not in AXES:
            raise SpecError(f"{where}.where: unknown axis {k!r}; allowed: {sorted(AXES)} "
                            "(select seeds with epochs.seeds)")
        vals = vals if isinstance(vals, list) else [vals]
        out["where"][k] = [_check_axis(k, x, f"{where}.where.{k}[{i}]", base, scalar=True,
                                       plugins=plugins)
                           for i, x in enumerate(vals)]
    return out


def _check_study_table(p: object, where: str, base: Path | None, key: str,
                       folder: Callable[[object, Path | None, str], Path | None],
                       example: str) -> dict:
    """A table that declares another study's folder under one ``key`` (``[page] flight``,
    ``[report] sensitivity``), checked by ``folder`` (:func:`_study_folder`'s path rule)."""
    if not isinstance(p, dict):
        raise SpecError(f"{where}: must be a table, e.g. {example}")
    unknown = sorted(set(p) - {key})
    if unknown:
        raise SpecError(f"{where}: unknown key(s) {unknown}; allowed: ['{key}']")
    if key in p:
        folder(p[key], base, f"{where}.{key}")
    return dict(p)


def _check_page(p: object, where: str, base: Path | None) -> dict:
    """The ``[page]`` table: ``flight``, the folder whose ``flight_series.csv`` the page
    replays (:func:`flight_folder`); without it the page shows the run's own cells only."""
    return _check_study_table(p, where, base, "flight", flight_folder,
                              '[page] flight = "results/ultrasonic"')


def flight_folder(value: object, base: Path | None, where: str) -> Path | None:
    """The folder ``[page] flight`` names, or None while it holds no :data:`FLIGHT_FILE`
    (the page says so; ``python -m experiments.ultrasonic`` writes it): :func:`_study_folder`."""
    return _study_folder(value, base, where, FLIGHT_FILE, "results/ultrasonic")


def _check_report(p: object, where: str, base: Path | None) -> dict:
    """The ``[report]`` table: ``sensitivity``, the folder of the sensitivity study whose
    tables the ``Cause:`` lines quote (:func:`sensitivity_folder`); without it they say the
    causes were not re-measured."""
    return _check_study_table(p, where, base, "sensitivity", sensitivity_folder,
                              '[report] sensitivity = "results/sensitivity"')


def sensitivity_folder(value: object, base: Path | None, where: str) -> Path | None:
    """The folder ``[report] sensitivity`` names, or None while it holds no
    :data:`SENSITIVITY_FILE` (``python -m experiments.sensitivity`` writes it):
    :func:`_study_folder`."""
    return _study_folder(value, base, where, SENSITIVITY_FILE, "results/sensitivity")


def _study_folder(value: object, base: Path | None, where: str, marker: str,
                  example: str) -> Path | None:
    """The folder of another study a spec declares (``[page] flight``, ``[report]
    sensitivity``), or None while it holds no ``marker`` file. The file resolves by the one
    rule of :func:`_resolve` (relative to the spec's folder, then the project, never outside
    them); a folder without the file must still be named inside them."""
    if not isinstance(value, str) or not value.strip():
        raise SpecError(f"{where}: must be a folder path (string), e.g. "
                        f"\"{example}\", got {value!r}")
    p = Path(value)
    cands = [p, PROJECT_DIR / p] if base is None else [base / p, PROJECT_DIR / p]
    if any((c / marker).is_file() for c in cands):
        return _resolve(None, str(p / marker), base, where).parent
    if base is not None and (p.is_absolute() or ".." in p.parts):
        raise SpecError(f"{where}: {value!r} must be named relative to the spec's folder or "
                        "the project, inside them (no '..', not absolute)")
    return None


# --------------------------------------------------------------------------- plug-ins
_PLUGIN_NAME = re.compile(r"^[A-Za-z_][\w.:+-]*$")
_COLOR = re.compile(r"^#[0-9a-fA-F]{6}$")
#: Labels of the built-in table rows: a plug-in's label must differ from each.
_BUILTIN_LABELS = frozenset(label for t in REGISTRY
                            for label in (*(r[0] for r in t.rows), t.heading_row) if label)


def _load_plugins(data: dict, src: str) -> tuple[dict[str, Technique], dict[str, tuple]]:
    """The spec's plug-in techniques (README, Plug-in trackers): the ``[techniques]``
    tables checked, every plug-in's tracker built once with its options
    (:func:`estimator.trackers.base.load_tracker`, so a bad import path, class or option
    fails at load naming the field), its class's source file hashed. Returns (name ->
    entry, name -> (source file, sha256 prefix))."""
    tables = data.get("techniques", {})
    if not isinstance(tables, dict):
        raise SpecError(f"{src}: techniques: must be a table of [techniques.\"<name>\"] "
                        f"tables, got {tables!r}")
    for name, tab in tables.items():
        _check_plugin_table(name, tab, f"{src}: techniques.{name}")
    entries = plugin_entries(data, _entry_point_names(data, tables))
    labels: dict[str, str] = {}
    for name, ent in entries.items():
        where = _where(src, tables, data, name)
        if not _PLUGIN_NAME.match(name):
            raise SpecError(f"{where}: technique name {name!r}: letters, digits and _.:+- only")
        label = ent.rows[0][0]
        if label in _BUILTIN_LABELS or label in labels:
            raise SpecError(f"{where}.label: {label!r} is already the label of "
                            f"{labels.get(label, 'a built-in row')}; give a label of its own")
        labels[label] = repr(name)
    files = {name: _plugin_file(ent, _where(src, tables, data, name))
             for name, ent in entries.items()}
    return entries, files


def _where(src: str, tables: dict, data: dict, name: str) -> str:
    return f"{src}: techniques.{name}" if name in tables else f"{src}: {_first_use(data, name)}"


def _check_plugin_table(name: object, tab: object, where: str) -> None:
    """One ``[techniques."<name>"]`` table: its keys and their types."""
    if isinstance(name, str) and name in TECHNIQUES:
        raise SpecError(f"{where}: {name!r} is a built-in technique; a plug-in takes a name "
                        "of its own (and 'tracker = ...' to name its class)")
    if not isinstance(tab, dict):
        raise SpecError(f"{where}: must be a table (tracker, options, label, color), got "
                        f"{tab!r}")
    unknown = sorted(set(tab) - set(PLUGIN_KEYS))
    if unknown:
        raise SpecError(f"{where}: unknown key(s) {unknown}; allowed: {list(PLUGIN_KEYS)}")
    tracker = tab.get("tracker", name)
    if not isinstance(tracker, str) or not tracker:
        raise SpecError(f"{where}.tracker: must be an import path 'package.module:ClassName' "
                        f"or an entry-point name, got {tracker!r}")
    if not isinstance(tab.get("options", {}), dict):
        raise SpecError(f"{where}.options: must be a table of option = value, got "
                        f"{tab['options']!r}")
    label = tab.get("label", "x")
    if not isinstance(label, str) or not label.strip() or len(label) > 60:
        raise SpecError(f"{where}.label: must be a non-empty string of at most 60 "
                        f"characters, got {label!r}")
    color = tab.get("color", "#000000")
    if not isinstance(color, str) or not _COLOR.match(color):
        raise SpecError(f"{where}.color: must be a colour '#rrggbb', got {color!r}")


def _technique_uses(data: dict) -> Iterable[tuple[str, object]]:
    """(where, value) of every ``technique`` the spec sets: "defaults", "grid[1]", ..."""
    for where, b in [("defaults", data.get("defaults") or {}),
                     *((f"grid[{i}]", b) for i, b in enumerate(data.get("grid") or []))]:
        yield where, b.get("technique") if isinstance(b, dict) else None


def _entry_point_names(data: dict, tables: dict) -> list[str]:
    """``technique`` values of the spec that name an installed entry point of the group
    ``configpose.trackers`` (and neither a built-in technique nor a table)."""
    values = [x for _, v in _technique_uses(data) for x in (v if isinstance(v, list) else [v])
              if isinstance(x, str) and ":" not in x and x not in TECHNIQUES
              and x not in tables]
    if not values:
        return []
    import importlib.metadata

    # imported only here: the tracker family (pandas, scipy) costs ~1 s to import, which a
    # spec without entry-point names (every preset) would pay before its first simulation
    from estimator.trackers.base import ENTRY_POINT_GROUP

    eps = {ep.name for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}
    return [x for x in dict.fromkeys(values) if x in eps]


def _first_use(data: dict, name: str) -> str:
    """Where the spec first names technique ``name``: "grid[1].technique[2]" or the like."""
    for where, v in _technique_uses(data):
        if isinstance(v, list) and name in v:
            return f"{where}.technique[{v.index(name)}]"
        if v == name:
            return f"{where}.technique"
    return "technique"


def _plugin_file(entry: Technique, where: str) -> tuple[str, str]:
    """Build the plug-in's tracker once (its import path, class and options checked) and
    return its class's source file with the file's sha256 prefix (part of its cells' keys:
    editing the file recomputes them)."""
    import inspect

    from estimator.trackers.base import TrackerLoadError, load_tracker

    try:
        tracker = load_tracker(entry.tracker, json.loads(entry.options))
    except TrackerLoadError as exc:
        raise SpecError(f"{where}: {exc}") from None
    try:
        path = Path(inspect.getsourcefile(type(tracker)) or "")
    except TypeError:
        path = Path()
    if not path.is_file():
        raise SpecError(f"{where}: the source file of {type(tracker).__name__} cannot be "
                        "found (a plug-in's cells are keyed by its source)")
    return str(path), _sha(path)


# --------------------------------------------------------------------------- loading
def available_presets() -> list[str]:
    """Names of the shipped presets in ``experiments/presets/``."""
    return sorted(p.stem for p in PRESETS_DIR.glob("*.toml"))


def load_spec(path_or_name: str | Path) -> Spec:
    """Load a spec from a TOML file, or a preset by name (``experiments/presets/<name>.toml``).

    Raises :class:`SpecError` naming the file and field for any invalid content.
    """
    p = Path(path_or_name)
    bare = not p.suffix and p.parent == Path(".")
    p = resolve_model_file(path_or_name, PRESETS_DIR,
                           f"{'preset' if bare else 'spec'} {str(path_or_name)!r}",
                           error=SpecError)
    data = parse_toml(p.read_bytes(), p, error=SpecError)
    return Spec.from_dict(data, source=str(p), base_dir=p.resolve().parent)
