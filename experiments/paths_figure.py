"""Figure of the simulated truth paths: the GPS rover on Path 1 and the quadcopter square.

    python -m experiments.paths_figure              # -> results/local/figures/paths.png (ignored)
    python -m experiments.paths_figure --reference  # -> the committed results/figures/paths.png
    python -m experiments.paths_figure --out /tmp/paths.png

Left: the rover (sim.rover) driving Path 1 of the GPS dissertation (Section 4.9), its
reference point at 10 Hz, with the 3 m target areas around the corners and an inset of the
first corner (the curved turn inside the target area). Right: the quadcopter
(sim.quadcopter) flying ``quad_square6`` above the ultrasonic receivers (thesis 003).
Segments where the controller's turning flag is set are drawn in orange. Both simulations
come from the truth cache (results/cache/truth), so re-plotting does not re-simulate.
"""

from __future__ import annotations

import argparse
from pathlib import Path as FsPath
from typing import TYPE_CHECKING

import numpy as np

from estimator.configuration import SensorConfig
from experiments.spec import RESULTS_ROOT
from sim.cache import DEFAULT_CACHE_DIR
from sim.paths import Path, load_path, path_errors
from sim.truth import Truth

if TYPE_CHECKING:
    from matplotlib.axes import Axes

__all__ = ["draw_panel", "main", "plot_paths"]

#: The committed figure; written only by ``--reference``.
REFERENCE_OUT = RESULTS_ROOT / "figures" / "paths.png"
#: Default output of every other run (``results/local/`` is ignored by git).
DEFAULT_OUT = RESULTS_ROOT / "local" / "figures" / "paths.png"
DEFAULT_ROVER_PATH, DEFAULT_QUAD_PATH = "square100", "quad_square6"
ROVER_FIGURE_RATE_HZ = 10.0   # denser than the 1 Hz GPS truth so the curved turns show


def _turning_runs(turning: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index ranges (stop exclusive) of consecutive True samples."""
    edges = np.diff(np.concatenate([[0], turning.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def draw_panel(ax: Axes, truth: Truth, path: Path, title: str, *,
               inset_corner: int | None = None, inset_half_m: float = 5.0) -> None:
    """Draw one platform: waypoint polyline, target areas, truth CG path, turning segments.

    ``inset_corner`` (index into ``path.corners``) adds a zoomed inset around that corner.
    """
    from matplotlib.patches import Circle

    def draw(a: Axes, label: bool) -> None:
        V = path.polyline[:, :2]
        a.plot(V[:, 0], V[:, 1], "--", color="0.55", lw=1,
               label="waypoint polyline" if label else None)
        for k, c in enumerate(path.corners[:, :2]):
            a.add_patch(Circle(c, path.target_radius_m, fill=False, ls=":", color="tab:blue", lw=1,
                               label="target area" if (label and k == 0) else None))
        a.plot(path.corners[:, 0], path.corners[:, 1], "x", color="tab:blue", ms=7,
               label="corners" if label else None)
        a.plot(path.start[0], path.start[1], "o", mfc="none", color="k", ms=7,
               label="start / end" if label else None)
        xy = truth.cg[:, :2]
        a.plot(xy[:, 0], xy[:, 1], "-", color="tab:green", lw=1.4,
               label="truth CG" if label else None)
        for i, (s, e) in enumerate(_turning_runs(truth.turning)):
            lo, hi = max(s - 1, 0), min(e + 1, truth.n)
            a.plot(xy[lo:hi, 0], xy[lo:hi, 1], "-", color="tab:orange", lw=2.2,
                   label="turning flag" if (label and i == 0) else None)
        a.set_aspect("equal")

    draw(ax, True)
    e = path_errors(truth.cg, path)
    ax.set_title(f"{title}\ncut-in {np.mean(e.cut_in_m):.2f} m, straights max "
                 f"{1000 * e.straight_max_m:.1f} mm, closure {1000 * e.closure_m:.1f} mm",
                 fontsize=9)
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    if inset_corner is None:
        ax.legend(loc="center", fontsize=7, frameon=False)
    else:
        ax.legend(loc="lower center", bbox_to_anchor=(0.5, 0.06), fontsize=7, frameon=False)
    if inset_corner is not None:
        c = path.corners[inset_corner, :2]
        ins = ax.inset_axes([0.30, 0.40, 0.40, 0.40])
        draw(ins, False)
        ins.set_xlim(c[0] - inset_half_m, c[0] + inset_half_m)
        ins.set_ylim(c[1] - inset_half_m, c[1] + inset_half_m)
        ins.tick_params(labelsize=6)
        ins.set_title(f"corner ({c[0]:g}, {c[1]:g})", fontsize=7)
        ax.indicate_inset_zoom(ins, edgecolor="0.4")


def plot_paths(panels: list[tuple[Truth, Path, str, int | None]], out: str | FsPath) -> FsPath:
    """Write a row of panels ``(truth, path, title, inset_corner)`` to ``out`` (PNG)."""
    from matplotlib.figure import Figure

    out = FsPath(out)
    fig = Figure(figsize=(6.2 * len(panels), 6.2))   # no pyplot: no GUI backend needed
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, (truth, path, title, inset) in zip(axes[0], panels):
        draw_panel(ax, truth, path, title, inset_corner=inset)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=130)
    return out


def _rel(p: FsPath) -> str:
    """``p`` relative to the results folder's parent when inside it (for messages)."""
    try:
        return str(p.resolve().relative_to(RESULTS_ROOT.parent.resolve()))
    except ValueError:
        return str(p)


def _output(ap: argparse.ArgumentParser, args: argparse.Namespace) -> FsPath:
    """Where the figure goes: the committed reference only with ``--reference`` (which takes
    the default paths and no ``--out``), else ``--out`` or the ignored default."""
    if args.reference:
        if (args.out is not None or args.rover_path != DEFAULT_ROVER_PATH
                or args.quad_path != DEFAULT_QUAD_PATH):
            ap.error("--reference regenerates the committed figure with the default paths; it "
                     "takes no --out, --rover-path or --quad-path")
        return REFERENCE_OUT
    out = FsPath(args.out) if args.out is not None else DEFAULT_OUT
    if out.resolve() == REFERENCE_OUT.resolve():
        ap.error(f"--out {args.out}: {_rel(REFERENCE_OUT)} is the committed reference; "
                 "regenerate it with --reference, write other figures elsewhere")
    return out


def main(argv: list[str] | None = None) -> FsPath:
    """CLI: simulate (or load from the cache) both platforms and write the figure."""
    from experiments.cli import ArgumentParser

    ap = ArgumentParser(prog="python -m experiments.paths_figure",
                        description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None,
                    help=f"output PNG (default {_rel(DEFAULT_OUT)}, ignored by git; "
                         f"{_rel(REFERENCE_OUT)} only through --reference)")
    ap.add_argument("--reference", action="store_true",
                    help=f"regenerate the committed {_rel(REFERENCE_OUT)} (default paths)")
    ap.add_argument("--rover-path", default=DEFAULT_ROVER_PATH)
    ap.add_argument("--quad-path", default=DEFAULT_QUAD_PATH)
    ap.add_argument("--no-cache", action="store_true", help="simulate without the truth cache")
    args = ap.parse_args(argv)
    target = _output(ap, args)

    from sim.quadcopter import simulate_quadcopter
    from sim.rover import simulate_rover

    rover_path, quad_path = load_path(args.rover_path), load_path(args.quad_path)
    rover = simulate_rover(rover_path, SensorConfig.load("rover_gps8"),
                           sample_rate_hz=ROVER_FIGURE_RATE_HZ,
                           cache_dir=False if args.no_cache else None)
    quad = simulate_quadcopter(quad_path, cache_dir=None if args.no_cache else DEFAULT_CACHE_DIR)
    out = plot_paths([
        (rover, rover_path, f"GPS rover, {rover_path.name} at {rover_path.cruise_speed_mps:g} m/s",
         0),
        (quad, quad_path, f"quadcopter, {quad_path.name} at {quad_path.altitude_m:g} m", None),
    ], target)
    for name, tr, p in (("rover", rover, rover_path), ("quadcopter", quad, quad_path)):
        e = path_errors(tr.cg, p)
        print(f"{name:10s} {p.name}: {tr.t[-1]:.1f} s, cut-in per corner "
              f"{np.round(e.cut_in_m, 3).tolist()} m, straights max {e.straight_max_m:.4f} m, "
              f"closure {e.closure_m:.4f} m")
    print(f"wrote {out}")
    return out


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
