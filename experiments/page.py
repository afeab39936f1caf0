"""A run's web page: ``results/<name>/index.html``, one self-contained file that opens from disk.

``python -m experiments.sweep`` and ``python -m experiments.report DIR`` write it after the
tables and figures; ``python -m experiments.page DIR`` rewrites it alone (no simulation, no
estimation). The page shows

- a replay of every cell with saved per-epoch estimates (the spec's ``[epochs]`` table):
  choose the cell by its axes (path, window, technique, weighting, seed, ... whatever the
  sweep varied); the true path and the estimate over the whole square, a close-up with the
  platform drawn as its antenna layout (outline: the convex hull, :mod:`experiments.outline`)
  at the estimated and at the true pose, heading arrows and the observed antennas of that
  epoch; a time slider and a play button; below, the error
  over time (x, y, heading) with the turning sections shaded (the live display of position
  and heading that the ultrasonic thesis's DAQ program gave, 003_691aa933e2e3c7e2.txt
  Fig 3.4, for every cell of a run);
- the same for any other results folder passed with ``--with`` (e.g. a real-data recording
  run, contract below);
- the ultrasonic flight (``flight_series.csv`` of ``python -m experiments.ultrasonic``) when
  the run's spec declares its folder (``[page] flight = "results/ultrasonic"``, as the thesis
  preset does; recorded in ``manifest.json``) or ``--ultrasonic DIR`` names it, never by
  default: receivers, both transmitters (true and Kalman-estimated), the gated trilateration
  fix, and range rays from every receiver with the raw and the gated range, plus ranges,
  position and heading error over time;
- the claim report (``REPORT.md``) with its verdicts, the tables (``tables.md``: Tables
  4.1/4.2 with intervals, weighting, orientation, beyond rows, and whatever else the run
  wrote there) and every PNG figure of the folder.

Why plain JavaScript on <canvas> rather than Bokeh or Plotly: the replay is custom drawing
(antenna polygons at two poses, heading arrows, range rays, cell switching) that either
library would need hand-written JS callbacks for anyway, and a page that opens without
network would have to inline the library's whole runtime; the page's own script (about 30 kB)
does the drawing, has no dependency to keep up to date, and the page is written in about half
a second (README). The script and style live in ``experiments/page_assets/`` and are
inlined, with the data as JSON (float arrays as base64 float32), so the page needs no network
and no server; the figures are the PNG files beside it (relative links, the folder moves as a
whole).

File contract for a replay source (what the sweep writes; a recording run that writes the
same is replayed the same way; ``tests/test_page.py`` checks it on a synthetic folder):

- ``cells.parquet``: one row per cell (and mask), columns ``key``, the cell's axis columns,
  then ``mask`` and statistics (the layout of :class:`experiments.sweep.CellStore`), and
  ``has_epochs`` (bool). Axis columns are those between ``key`` and ``mask``; without a
  ``mask`` column, the axes of :data:`experiments.spec.AXES` plus ``seed`` and ``recording``
  that are present. Selectors are offered for the axes that vary among the cells with epochs.
- ``epochs/<key>.parquet`` for every cell with ``has_epochs``: required ``t`` (s, increasing),
  ``cg_x``, ``cg_y`` (m, world x east / y north), ``yaw`` (rad, CCW from +x); optional
  reference ``truth_cg_x``, ``truth_cg_y``, ``truth_yaw`` (absent or all NaN: the page shows
  the estimate without errors), ``truth_turning`` (bool, shaded), per-antenna
  ``truth_<name>_x/_y`` (the antenna layout is recovered from them, else from the estimated
  ``x_<name>``/``y_<name>``), and observations ``obs_<name>_x/_y`` (NaN = not received).
  Large coordinates (UTM) are fine: positions are stored relative to a rounded origin.

Size: each replay keeps at most ``max_points`` epochs per track (every k-th epoch, picked,
not averaged, so the jitter stays visible; the page says when it does); the thesis preset's
page (78 cells with epochs) is 2.3 MB (measured, README).
"""

from __future__ import annotations

import base64
import html
import json
import math
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from experiments.outline import layout_outline
from sim.atomic import atomic_write_text

__all__ = ["ASSETS", "build_page", "declared_flight", "flight_dir", "flight_source", "main",
           "own_replay", "replay_source", "write_page"]

ASSETS = Path(__file__).resolve().parent / "page_assets"
REPO = Path(__file__).resolve().parents[1]

#: Axes that only change the estimate, not the truth it is scored against; the other axes
#: (path, config, path_overrides, recording, ...) define a track (one truth).
ESTIMATOR_AXES = ("window", "weighting", "technique", "solver", "dyn_window", "turning", "seed",
                  "noise", "noise_overrides")
#: Axes that change the observations (with the track): cells sharing them share observations.
NOISE_AXES = ("noise", "noise_overrides", "seed")
REQUIRED = ("t", "cg_x", "cg_y", "yaw")
#: Per-cell statistics shown beside the replay (label, column, scale, unit), if present.
CELL_STATS = (("mean |x|", "ex_mean", 1.0, "m"), ("mean |y|", "ey_mean", 1.0, "m"),
              ("RMSE", "eu_rmse", 1.0, "m"), ("mean |heading|", "eh_mean", 180 / math.pi, "deg"))
_CLAIM_VERDICTS = ("reproduced", "mixed", "not reproduced", "not evaluated")


# --------------------------------------------------------------------------- encoding
def _b64(a: np.ndarray, dtype: str = "<f4") -> str:
    """Base64 of the array's bytes as little-endian ``dtype`` (what page.js decodes)."""
    with np.errstate(over="ignore"):          # beyond float32 (|v| > 3e38): inf, not drawn
        raw = np.ascontiguousarray(a, dtype=dtype).tobytes()
    return base64.b64encode(raw).decode("ascii")


def _origin(*arrays: np.ndarray) -> float:
    """0 for local coordinates (|values| < 10 km); else a rounded offset (UTM-sized values
    would lose centimetres in float32)."""
    vals = np.concatenate([np.asarray(a, float).ravel() for a in arrays if a is not None]
                          or [np.zeros(0)])
    vals = vals[np.isfinite(vals)]
    if vals.size == 0 or np.abs(vals).max() < 1e4:
        return 0.0
    return float(np.round(np.median(vals), -2))


class _EpochFile:
    """Columns of one ``epochs/<key>.parquet``, read on demand (pyarrow, no pandas frame)."""

    def __init__(self, path: Path):
        import pyarrow.parquet as pq

        self.path = path
        self._file = pq.ParquetFile(path)      # footer parsed once, columns read on demand
        self.names = self._file.schema_arrow.names
        self._cols: dict[str, np.ndarray] = {}
        missing = [c for c in REQUIRED if c not in self.names]
        if missing:
            raise ValueError(f"{path}: missing columns {missing}")

    def __contains__(self, name: str) -> bool:
        return name in self.names

    def load(self, names: list[str]) -> None:
        want = [n for n in names if n in self.names and n not in self._cols]
        if want:
            tb = self._file.read(columns=want)
            for n in want:
                self._cols[n] = tb.column(n).to_numpy(zero_copy_only=False)

    def get(self, name: str, dtype: type = float) -> np.ndarray | None:
        """Column as ``dtype`` (float: None when absent or entirely non-finite)."""
        if name not in self.names:
            return None
        self.load([name])
        v = np.asarray(self._cols[name]).astype(dtype, copy=False)
        return None if dtype is float and not np.isfinite(v).any() else v


# --------------------------------------------------------------------------- GPS replays
def _axis_columns(cells: pd.DataFrame) -> list[str]:
    cols = list(cells.columns)
    if "key" in cols and "mask" in cols and cols.index("mask") > cols.index("key"):
        return cols[cols.index("key") + 1:cols.index("mask")]
    from experiments.spec import AXES

    return [a for a in (*AXES, "seed", "recording") if a in cols]


def _antenna_names(ep: _EpochFile) -> list[str]:
    names = [m.group(1) for c in ep.names if (m := re.fullmatch(r"truth_(.+)_x", c))
             and m.group(1) != "cg" and f"truth_{m.group(1)}_y" in ep]
    return names or [c[2:] for c in ep.names if c.startswith("x_") and f"y_{c[2:]}" in ep]


def _body_layout(ep: _EpochFile, names: list[str]) -> np.ndarray | None:
    """(m, 2) antenna positions in the body frame (x forward, y left, origin at the CG),
    recovered as the median over epochs of R(-yaw) (p - cg): from the true antennas and pose
    when the table has them, else from the estimated antennas and pose."""
    for px, py, cx, cy, yaw in (("truth_{}_x", "truth_{}_y", "truth_cg_x", "truth_cg_y",
                                 "truth_yaw"), ("x_{}", "y_{}", "cg_x", "cg_y", "yaw")):
        cols = [cx, cy, yaw, *(f.format(n) for n in names for f in (px, py))]
        if not all(c in ep for c in cols):
            continue
        ep.load(cols)
        th = ep.get(yaw)
        if th is None:
            continue
        c, s = np.cos(th)[:, None], np.sin(th)[:, None]
        dx = np.stack([ep.get(px.format(n)) for n in names], 1) - ep.get(cx)[:, None]
        dy = np.stack([ep.get(py.format(n)) for n in names], 1) - ep.get(cy)[:, None]
        bx, by = c * dx + s * dy, -s * dx + c * dy
        ok = np.isfinite(bx) & np.isfinite(by)
        if not ok.any(axis=0).all():
            continue
        with np.errstate(all="ignore"):
            return np.stack([np.nanmedian(np.where(ok, bx, np.nan), 0),
                             np.nanmedian(np.where(ok, by, np.nan), 0)], 1)
    return None


def _track(ep: _EpochFile, max_points: int) -> dict:
    """A track's payload (time grid, reference, turning flags, antenna layout) from its
    longest epochs file; keys starting with "_" are for building only."""
    ep.load(["truth_cg_x", "truth_cg_y", "truth_yaw", "truth_turning"])
    t_full = ep.get("t")
    step = max(1, math.ceil(len(t_full) / max_points))
    idx = np.arange(0, len(t_full), step)
    names = _antenna_names(ep)
    body = _body_layout(ep, names) if names else None
    if body is None:               # no antenna columns: the CG as a one-point "layout"
        names, body = ["cg"], np.zeros((1, 2))
    tx, ty, tyaw = (ep.get(c) for c in ("truth_cg_x", "truth_cg_y", "truth_yaw"))
    has_truth = tx is not None and ty is not None and tyaw is not None
    x0 = _origin(tx if has_truth else ep.get("cg_x"))
    y0 = _origin(ty if has_truth else ep.get("cg_y"))
    t0 = float(t_full[0]) if abs(t_full[0]) > 1e5 else 0.0      # epoch-second clocks
    tr: dict[str, Any] = {
        "t": _b64(t_full[idx] - t0), "t0": t0, "origin": [x0, y0], "step": step,
        "n_full": int(len(t_full)), "names": names, "body": np.round(body, 4).tolist(),
        "outline": layout_outline(np.round(body, 4)),    # convex hull, never angle order
        "truth": None, "turning": None,
        "_t": t_full, "_idx": idx, "_names": names, "_tx": tx if has_truth else None}
    if has_truth:
        tr["truth"] = {"x": _b64(tx[idx] - x0), "y": _b64(ty[idx] - y0), "yaw": _b64(tyaw[idx])}
    turn = ep.get("truth_turning", bool)
    if turn is not None:
        tr["turning"] = _b64(turn[idx], "u1")
    return tr


def _on_track(tr: dict, ep: _EpochFile) -> np.ndarray | None:
    """Positions of the file's epochs on the track's time grid, or None when its times or
    its reference differ from the track's (then it belongs to another track)."""
    t_full, tk = tr["_t"], ep.get("t")
    pos = np.clip(np.searchsorted(t_full, tk), 0, len(t_full) - 1)
    if not np.allclose(t_full[pos], tk, rtol=0, atol=1e-6):
        return None
    if tr["_tx"] is not None:
        tx = ep.get("truth_cg_x")
        if tx is None or not np.allclose(tr["_tx"][pos], tx, rtol=0, atol=1e-9, equal_nan=True):
            return None
    return pos


def replay_source(results: str | Path, *, max_points: int = 1000, title: str | None = None
                  ) -> dict | None:
    """The replay payload of one results folder (see the module's file contract), or None
    when it has no cell with saved epochs.

    Cells are grouped into tracks (one truth: equal non-estimator axes and an equal
    reference at shared epochs) and noise groups (equal observations); each track keeps
    every k-th epoch, k = ceil(n / max_points). Raises ValueError naming the file when an
    epochs file lacks a required column.
    """
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) \
            or max_points < 2:
        raise ValueError(f"max_points: must be an integer >= 2, got {max_points!r}")
    results = Path(results)
    cells = pd.read_parquet(results / "cells.parquet")
    if "has_epochs" not in cells or "key" not in cells:
        return None
    axes = _axis_columns(cells)
    with_ep = cells[cells["has_epochs"].astype(bool)]
    if "mask" in with_ep:         # one row per cell: its full-path row when there is one
        with_ep = with_ep.iloc[np.argsort((with_ep["mask"] != "full").to_numpy(), kind="stable")]
    first = with_ep.drop_duplicates("key").set_index("key")
    keys = [k for k in first.index if (results / "epochs" / f"{k}.parquet").exists()]
    if not keys:
        return None
    first = first.loc[keys].copy()
    for a in axes:
        first[a] = first[a].astype(str)
    varying = [a for a in axes if first[a].nunique() > 1]
    fixed = {a: first[a].iloc[0] for a in axes if a not in varying}
    track_axes = [a for a in axes if a not in ESTIMATOR_AXES]
    files = {k: _EpochFile(results / "epochs" / f"{k}.parquet") for k in keys}
    for ep in files.values():
        ep.load([*REQUIRED, "truth_cg_x"])

    # tracks: group by the non-estimator axes; the longest file defines the time grid; a
    # file whose times or reference do not fit starts a track of its own
    groups: dict[tuple, list[str]] = {}
    for k in keys:
        groups.setdefault(tuple(first.loc[k, a] for a in track_axes), []).append(k)
    pending = [sorted(g, key=lambda k: -len(files[k].get("t"))) for g in groups.values()]
    tracks: list[dict] = []
    where: dict[str, tuple[int, np.ndarray]] = {}
    while pending:
        group = pending.pop(0)
        tr = _track(files[group[0]], max_points)
        rest = []
        for k in group:
            pos = _on_track(tr, files[k])
            if pos is None:
                rest.append(k)
            else:
                where[k] = (len(tracks), pos)
        tracks.append(tr)
        if rest:
            pending.append(rest)

    noise: list[dict] = []
    noise_of: dict[tuple, list[int]] = {}
    out_cells = []
    for k in keys:
        ti, pos = where[k]
        tr, ep = tracks[ti], files[k]
        idx, n, (x0, y0) = tr["_idx"], len(tr["_t"]), tr["origin"]

        def on_grid(v: np.ndarray, pos=pos, n=n, idx=idx) -> np.ndarray:
            full = np.full(n, np.nan)
            full[pos] = v
            return full[idx]

        # observations: shared by the cells of a track with equal noise axes (checked on
        # the first antenna, so a grouping mistake cannot pass silently)
        ni = -1
        obs_cols = [f"obs_{nm}_{a}" for nm in tr["_names"] for a in "xy"]
        if all(c in ep for c in obs_cols):
            nkey = (ti, *(first.loc[k, a] for a in NOISE_AXES if a in first))
            probe = on_grid(ep.get(obs_cols[0], np.float64))
            for cand in noise_of.get(nkey, []):
                if np.array_equal(noise[cand]["_probe"], probe, equal_nan=True):
                    ni = cand
                    break
            if ni < 0:
                ep.load(obs_cols)
                obs = np.stack([np.stack([on_grid(ep.get(f"obs_{nm}_x", np.float64)) - x0,
                                          on_grid(ep.get(f"obs_{nm}_y", np.float64)) - y0], 1)
                                for nm in tr["_names"]], 1)          # (N, m, 2)
                dead = (~np.isfinite(obs).any(axis=2)).all(axis=0)
                ni = len(noise)
                noise.append({"track": ti, "obs": _b64(obs), "dead": dead.tolist(),
                              "_probe": probe})
                noise_of.setdefault(nkey, []).append(ni)
        row = first.loc[k]
        stats = []
        for label, col, scale, unit in CELL_STATS:
            if col in row and pd.notna(row[col]) and np.isfinite(float(row[col])):
                stats.append([label, f"{float(row[col]) * scale:.3g} {unit}"])
        out_cells.append({
            "key": k, "axes": {a: row[a] for a in axes}, "track": ti, "noise": ni,
            "x": _b64(on_grid(ep.get("cg_x", np.float64)) - x0),
            "y": _b64(on_grid(ep.get("cg_y", np.float64)) - y0),
            "yaw": _b64(on_grid(ep.get("yaw", np.float64))), "stats": stats})
    for d in (*tracks, *noise):
        for k in [k for k in d if k.startswith("_")]:
            del d[k]
    out_cells.sort(key=lambda c: tuple(_sort_key(c["axes"][a]) for a in varying))
    labels = {}
    if "path" in varying:
        from experiments.tables import PATH_LABELS

        labels["path"] = {p: f"{p} ({PATH_LABELS[p]})" for p in first["path"].unique()
                          if p in PATH_LABELS}
    dec = any(t["step"] > 1 for t in tracks)
    note = (f"{len(out_cells)} cells with saved epochs, {len(tracks)} track(s)"
            + (f"; replay decimated to at most {max_points} epochs per track" if dec else ""))
    # first shown: the plainest cell (most axes "none": no weights, no technique)
    plain = [sum(v == "none" for v in c["axes"].values()) for c in out_cells]
    return {"title": title or results.name, "note": note, "axes": varying, "fixed": fixed,
            "labels": labels, "tracks": tracks, "noise": noise, "cells": out_cells,
            "default": int(np.argmax(plain))}


def _sort_key(v: str) -> tuple:
    try:
        return (0, float(v), "")
    except ValueError:
        return (1, 0.0, v)


# --------------------------------------------------------------------------- flight
def flight_source(ultrasonic: str | Path, *, max_points: int = 5000) -> dict | None:
    """Replay payload of the ultrasonic flight (``flight_series.csv`` of
    ``python -m experiments.ultrasonic``), or None when the file is absent.

    Both transmitters: the rear one is 2 * mid - front (the CSV keeps the front and the
    midpoint, true and Kalman-estimated). Receivers: ``models/receivers/flight.toml`` as the
    study loads it; the receivers used for trilateration from ``run_info.json``. Ranges are
    those of the front transmitter (the only ones the CSV keeps): true, raw and gated (the
    first gate column set other than raw/true, ``robust`` in today's study).
    """
    f = Path(ultrasonic) / "flight_series.csv"
    if not f.exists():
        return None
    s = pd.read_csv(f)
    need = ["t", *(f"{w}_true_{a}" for w in ("front", "mid") for a in "xyz")]
    missing = [c for c in need if c not in s]
    if missing:
        raise ValueError(f"{f}: missing columns {missing}")
    step = max(1, math.ceil(len(s) / max_points))
    s = s.iloc[::step].reset_index(drop=True)
    t = s["t"].to_numpy(float)

    def xyz(prefix: str, mid: str | None = None, rear: bool = False) -> dict | None:
        if not all(f"{prefix}_{a}" in s for a in "xyz"):
            return None
        out = {}
        for a in "xyz":
            v = s[f"{prefix}_{a}"].to_numpy(float)
            if rear:
                v = 2 * s[f"{mid}_{a}"].to_numpy(float) - v
            out[a] = _b64(v)
        return out

    from sim.ultrasonic import load_receivers

    info_p = Path(ultrasonic) / "run_info.json"
    info = json.loads(info_p.read_text()) if info_p.exists() else {}
    fl = info.get("flight", {})
    if "receivers_m" in fl and "receiver_names" in fl:
        rnames, rec = list(fl["receiver_names"]), np.asarray(fl["receivers_m"], float)
    else:
        names, rec = load_receivers("flight")
        rnames = list(names)
    used = [n for n in fl.get("triple", []) if n in rnames]
    kinds = sorted({m.group(1) for c in s.columns
                    if (m := re.fullmatch(r"range_(\w+?)_front_(\w+)", c))})
    gated = next((k for k in ("robust", *kinds) if k in kinds and k not in ("true", "raw")), None)
    rng = {"names": [n for n in rnames if f"range_raw_front_{n}" in s]}
    for k, kind in (("true", "true"), ("raw", "raw"), ("gated", gated)):
        rng[k] = {n: _b64(s[f"range_{kind}_front_{n}"].to_numpy(float)) for n in rnames
                  if kind and f"range_{kind}_front_{n}" in s}
    yaw_t = s["yaw_true"].to_numpy(float) if "yaw_true" in s else np.full(len(s), np.nan)
    est_yaw = next((c for c in ("yaw_filtered", "yaw_cmd") if c in s), None)
    return {
        "title": "ultrasonic flight", "t": _b64(t - t[0]), "t0": float(t[0]),
        "receivers": {"names": rnames, "xyz": np.round(rec, 5).tolist(), "used": used},
        "truth": {"front": xyz("front_true"), "rear": xyz("front_true", "mid_true", True),
                  "yaw": _b64(yaw_t)},
        "est": {"front": xyz("front_kf"), "rear": xyz("front_kf", "mid_kf", True)
                if "mid_kf_x" in s else None, "cmd": xyz("front_cmd"),
                "yaw": _b64(s[est_yaw].to_numpy(float)) if est_yaw else None},
        "ranges": rng, "gated_kind": gated, "step": step,
    }


# --------------------------------------------------------------------------- HTML
def _markdown(text: str) -> str:
    from markdown_it import MarkdownIt

    md = MarkdownIt("commonmark", {"html": False}).enable("table")
    out = md.render(text)
    out = out.replace("<table>", '<div class="tablewrap"><table>').replace("</table>",
                                                                         "</table></div>")

    def badge(m: re.Match) -> str:
        v = m.group(1)
        return f'<span class="verdict v-{v.replace(" ", "-")}">{v}</span>'

    return re.sub(r"<strong>(" + "|".join(_CLAIM_VERDICTS) + r")</strong>", badge, out)


def _claims_summary(results: Path) -> str:
    """Verdict counts per variant from claims.csv (one verdict per claim)."""
    f = results / "claims.csv"
    if not f.exists():
        return ""
    c = pd.read_csv(f, keep_default_na=False)
    if not {"claim", "verdict"} <= set(c.columns):
        return ""
    var = c["variant"] if "variant" in c else pd.Series([""] * len(c))
    parts = []
    for v, g in c.assign(variant=var).groupby("variant", sort=False):
        per = g.drop_duplicates("claim")["verdict"].value_counts()
        badges = "".join(f'<span class="verdict v-{k.replace(" ", "-")}">'
                         f"{html.escape(k)}: {n}</span>" for k, n in per.items())
        parts.append(f'<div class="badges">{html.escape(v) + ": " if v else ""}{badges}</div>')
    return "".join(parts)


def _section(sid: str, title: str, body: str) -> str:
    return f'<section id="{sid}"><h2>{html.escape(title)}</h2>{body}</section>'


def _safe(label: str, fn, *args, **kw):
    """Run one part of the page; on failure, an error box in the page and a line on stderr
    (one broken part never hides the others or stops the sweep)."""
    try:
        return fn(*args, **kw), ""
    except Exception as exc:  # noqa: BLE001 - reported in the page and on stderr
        msg = f"{label}: {type(exc).__name__}: {exc}"
        print(f"page: {msg}", file=sys.stderr)
        return None, f'<div class="error-box">Could not build {html.escape(msg)}</div>'


def _manifest(results: Path) -> dict:
    """The run's manifest.json as a dict ({} when absent)."""
    f = results / "manifest.json"
    man = json.loads(f.read_text()) if f.exists() else {}
    return man if isinstance(man, dict) else {}


def _header(results: Path) -> tuple[str, str]:
    man = _manifest(results)
    spec = man.get("spec", {}) if isinstance(man.get("spec"), dict) else {}
    name = spec.get("name") or results.name
    code = man.get("code", {}) if isinstance(man.get("code"), dict) else {}
    bits = [f"{man.get('n_cells', '?')} cells", f"seeds {man.get('seeds', '?')}",
            f"spec seed {man.get('spec_seed', '?')}",
            f"code {code.get('git_describe') or code.get('git_commit') or '?'}"]
    # no run status or clock time: the page is written before the run is marked complete,
    # and a rerun of a committed reference must write the same page byte for byte
    if man.get("n_failed"):
        bits.append(f"<b>{man['n_failed']} failed cells (errors.json)</b>")
    desc = spec.get("description") or man.get("spec_raw", {}).get("description", "")
    meta = " \u00b7 ".join(bits)
    return name, (f"<h1>configpose run: {html.escape(str(name))}</h1>"
                  f"<div class=\"meta\">{html.escape(str(desc))}</div>"
                  f"<div class=\"meta\">{meta}</div>")


def own_replay(results: str | Path, max_points: int = 1000) -> tuple[dict | None, str]:
    """The replay of the results folder's own cells as :func:`build_page` makes it: (the
    :func:`replay_source` payload or None, the error box when it failed or ""). The sweep
    computes it in a worker beside the figures and hands it to :func:`write_page`."""
    results = Path(results)
    name, _ = _header(results)
    return _safe(f"the replay of {results}", replay_source, results, max_points=max_points,
                 title=f"{name} (this run)")


def declared_flight(results: str | Path) -> tuple[str, Path | None] | None:
    """The flight replay source the run's spec declared (``[page] flight`` in its
    ``manifest.json``): (the value as written, its folder resolved against the spec's folder
    by :func:`experiments.spec.flight_folder`, None while it holds no flight_series.csv),
    or None when the run declared none. A bad value raises SpecError naming the field."""
    man = _manifest(Path(results))
    spec = man.get("spec") if isinstance(man.get("spec"), dict) else {}
    value = (spec.get("page") or {}).get("flight")
    if value is None:
        return None
    from experiments.spec import flight_folder

    base = Path(man.get("spec_base_dir", "."))
    return value, flight_folder(value, base if base.is_absolute() else REPO / base,
                                "manifest.json: spec.page.flight")


def flight_dir(results: str | Path) -> Path | None:
    """The folder of the flight the run's page replays (:func:`declared_flight`), None when
    it declared none, the folder holds no flight series or the value is bad (the page shows
    why); what the outputs phase watches for changes."""
    try:
        declared = declared_flight(results)
    except ValueError:
        return None
    return None if declared is None else declared[1]


def _flight(results: Path, ultrasonic: str | Path | None) -> tuple[dict | None, str, str]:
    """(flight payload or None, error box or "", the source as the page names it) from
    ``ultrasonic`` when given, else from what the run declared (:func:`declared_flight`)."""
    if ultrasonic is not None:
        return (*_safe("the ultrasonic flight replay", flight_source, ultrasonic),
                str(ultrasonic))
    declared, err = _safe("the flight replay source", declared_flight, results)
    if declared is None:
        return None, err, ""
    value, folder = declared
    if folder is None:
        return None, ('<div class="error-box">The spec names the flight replay source '
                      f"<code>{html.escape(value)}</code> ([page] flight), which holds no "
                      "flight_series.csv yet (<code>python -m experiments.ultrasonic</code> "
                      "writes it).</div>"), value
    return (*_safe("the ultrasonic flight replay", flight_source, folder), value)


def build_page(results: str | Path, *, ultrasonic: str | Path | None = None,
               extra: tuple[str | Path, ...] = (), max_points: int = 1000,
               replay: tuple[dict | None, str] | None = None) -> str:
    """The HTML text of a results folder's page (see the module docstring).

    ultrasonic : folder with ``flight_series.csv`` (None: the one the run's spec declared
        with ``[page] flight``, else no flight replay).
    extra : further results folders (same file contract) replayed beside this one.
    max_points : epochs kept per track in a replay (every k-th epoch).
    replay : this folder's replay made beforehand by :func:`own_replay` (None: made here).
    """
    results = Path(results)
    name, head = _header(results)
    gps, errs = [], []
    for i, folder in enumerate((results, *extra)):
        if i == 0:
            src, err = replay if replay is not None else own_replay(results, max_points)
        else:
            src, err = _safe(f"the replay of {folder}", replay_source, folder,
                             max_points=max_points)
        errs.append(err)
        if src:
            gps.append(src)
    flight, ferr, fsrc = _flight(results, ultrasonic)

    nav, secs = [], []
    body = "".join(errs)
    for k, src in enumerate(gps):
        body += (f"<h3>{html.escape(src['title'])}</h3>"
                 f"<p class=\"note\">{html.escape(src['note'])}."
                 " Pick a cell with the selectors (the closest existing cell is taken when a "
                 "combination was not run), drag the slider or press play; click a time plot to "
                 "jump there. Keyboard: focus the slider and use the arrow keys, Home, End.</p>"
                 f'<div class="replay" id="replay-{k}"></div>')
    if not gps and not any(errs):
        body += ("<p class=\"note\">No cell of this run kept its per-epoch estimates (the spec's "
                 "<code>[epochs]</code> table selects them), so there is nothing to replay.</p>")
    nav.append(("replay", "Replay"))
    secs.append(_section("replay", "Replay of the cells", body))
    if flight or ferr:
        fbody = ferr
        if flight:
            fsrc = html.escape(f"{fsrc.rstrip('/')}/flight_series.csv")
            fbody += (f"<p class=\"note\">From <code>{fsrc}</code> "
                      "(<code>python -m experiments.ultrasonic</code>): the simulated quadcopter "
                      "square of thesis 003 Section 3.2 / Appendix C. Rays run from each receiver "
                      "towards the true front transmitter, as long as the measured range: a "
                      "spike shows as an orange ray that overshoots or stops short.</p>"
                      '<div class="replay" id="flight-replay"></div>')
        nav.append(("flight", "Ultrasonic flight"))
        secs.append(_section("flight", "Ultrasonic flight", fbody))
    for fname, sid, title, pre in (("REPORT.md", "claims", "Claims and verdicts", True),
                                   ("tables.md", "tables", "Tables", False)):
        f = results / fname
        if f.exists():
            text = f.read_text(encoding="utf-8")
            content, err = _safe(fname, _markdown, text)
            top = _claims_summary(results) if pre else ""
            nav.append((sid, title))
            secs.append(_section(sid, title, top + err + f'<div class="md">{content or ""}</div>'))
    figs = sorted(p.name for p in results.glob("*.png"))
    if figs:
        items = "".join(f'<figure><a href="{html.escape(n)}"><img src="{html.escape(n)}" '
                        f'loading="lazy" alt="{html.escape(n)}"></a>'
                        f"<figcaption>{html.escape(n)}</figcaption></figure>" for n in figs)
        nav.append(("figures", "Figures"))
        secs.append(_section("figures", "Figures", f'<div class="figs">{items}</div>'))

    data = json.dumps({"gps": gps, "flight": flight}, separators=(",", ":"), allow_nan=False)
    data = data.replace("</", "<\\/")
    css = (ASSETS / "page.css").read_text(encoding="utf-8")
    js = (ASSETS / "page.js").read_text(encoding="utf-8")
    navh = "".join(f'<a href="#{s}">{html.escape(t)}</a>' for s, t in nav)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>configpose: {html.escape(str(name))}</title><style>{css}</style></head>"
            f"<body><header>{head}<div class=\"meta\">written by "
            "<code>experiments/page.py</code>; opens from disk, no network</div></header>"
            f"<nav>{navh}</nav><main>{''.join(secs)}</main>"
            f'<script type="application/json" id="cp-data">{data}</script>'
            f"<script>{js}</script></body></html>\n")


def write_page(results: str | Path, *, out: str | Path | None = None,
               ultrasonic: str | Path | None = None,
               extra: tuple[str | Path, ...] = (), max_points: int = 1000,
               replay: tuple[dict | None, str] | None = None) -> Path:
    """Write ``<results>/index.html`` (or ``out``); returns its path. See :func:`build_page`."""
    results = Path(results)
    path = Path(out) if out is not None else results / "index.html"
    return atomic_write_text(path, build_page(results, ultrasonic=ultrasonic, extra=extra,
                                              max_points=max_points, replay=replay))


def _check_with(folder: Path, max_points: int) -> None:
    """A ``--with`` folder the user asked for must replay: else ValueError naming it (the
    CLI exits 2 and writes no page). Its replay is built here once to find out (the page
    builds it again: the cost of a recording run's replay, small)."""
    if not (folder / "cells.parquet").is_file():
        raise ValueError(f"--with {folder}: no cells.parquet there (not a sweep results "
                         "folder; run python -m experiments.sweep first)")
    try:
        src = replay_source(folder, max_points=max_points)
    except (ValueError, OSError) as exc:
        raise ValueError(f"--with {folder}: cannot be replayed: {exc}") from exc
    if src is None:
        raise ValueError(f"--with {folder}: no cell kept its per-epoch estimates (the spec's "
                         "[epochs] table), nothing to replay")


def main(argv: list[str] | None = None) -> int:
    from experiments.cli import ArgumentParser

    p = ArgumentParser(
        prog="python -m experiments.page",
        description="Write a results folder's self-contained web page (index.html): replay "
                    "of the cells with saved epochs, the ultrasonic flight, claims, tables, "
                    "figures. Example: python -m experiments.page results/thesis")
    p.add_argument("results", help="results folder of a sweep, e.g. results/thesis")
    p.add_argument("--with", dest="extra", nargs="*", default=[], metavar="DIR",
                   help="more results folders to replay on the same page (e.g. a recording "
                        "run), e.g. --with results/my_recording")
    p.add_argument("--ultrasonic", metavar="DIR",
                   help="folder with flight_series.csv to replay the ultrasonic flight from, "
                        "e.g. --ultrasonic results/ultrasonic (default: the folder the run's "
                        "spec declared with [page] flight, else no flight)")
    p.add_argument("--max-points", type=int, default=1000, metavar="N",
                   help="epochs kept per track in a replay (default 1000), e.g. --max-points 400")
    p.add_argument("--out", metavar="FILE", help="output file (default <results>/index.html)")
    args = p.parse_args(argv)
    res = Path(args.results)
    if not (res / "cells.parquet").exists():
        print(f"error: {res}/cells.parquet not found (run python -m experiments.sweep first)",
              file=sys.stderr)
        return 2
    if args.max_points < 2:
        print(f"error: --max-points: must be >= 2, got {args.max_points}", file=sys.stderr)
        return 2
    for folder in args.extra:
        _check_with(Path(folder), args.max_points)
    if args.ultrasonic is not None and not (Path(args.ultrasonic) / "flight_series.csv").is_file():
        raise ValueError(f"--ultrasonic {args.ultrasonic}: no flight_series.csv there (python -m "
                         "experiments.ultrasonic writes it)")
    path = write_page(res, out=args.out, ultrasonic=args.ultrasonic, extra=tuple(args.extra),
                      max_points=args.max_points)
    print(f"{path} ({path.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
