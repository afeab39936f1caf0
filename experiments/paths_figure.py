"""Figure of the simulated truth paths: the GPS rover on Path 1 and the quadcopter square.

    python -m experiments.paths_figure            # writes results/figures/paths.png

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

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Circle

from estimator.configuration import MODELS_DIR, SensorConfig
from sim.cache import DEFAULT_CACHE_DIR
from sim.paths import Path, load_path, path_errors
from sim.truth import Truth

__all__ = ["draw_panel", "main", "plot_paths"]

DEFAULT_OUT = MODELS_DIR.parent / "results" / "figures" / "paths.png"
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
    def draw(a: Axes, label: bool) -> None:
        V = path.polyline[:, :2]
        a.plot(V[:, 0], V[:, 1], "--", color="0.55", lw=1, label="waypoint polyline" if label else None)
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
    out = FsPath(out)
    fig = Figure(figsize=(6.2 * len(panels), 6.2))   # no pyplot: no GUI backend needed
    axes = fig.subplots(1, len(panels), squeeze=False)
    for ax, (truth, path, title, inset) in zip(axes[0], panels):
        draw_panel(ax, truth, path, title, inset_corner=inset)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=130)
    return out


def main(argv: list[str] | None = None) -> FsPath:
    """CLI: simulate (or load from the cache) both platforms and write the figure."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="output PNG (default %(default)s)")
    ap.add_argument("--rover-path", default="square100")
    ap.add_argument("--quad-path", default="quad_square6")
    ap.add_argument("--no-cache", action="store_true", help="simulate without the truth cache")
    args = ap.parse_args(argv)

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
    ], args.out)
    for name, tr, p in (("rover", rover, rover_path), ("quadcopter", quad, quad_path)):
        e = path_errors(tr.cg, p)
        print(f"{name:10s} {p.name}: {tr.t[-1]:.1f} s, cut-in per corner "
              f"{np.round(e.cut_in_m, 3).tolist()} m, straights max {e.straight_max_m:.4f} m, "
              f"closure {e.closure_m:.4f} m")
    print(f"wrote {out}")
    return out


if __name__ == "__main__":
    main()
