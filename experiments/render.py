"""Rendered clips of a run: the MuJoCo scenes drawn offscreen to an MP4 or a GIF.

    python -m experiments.render results/thesis --where path=square100 window=100 \\
        technique=lc+dyn weighting=huff dyn_growth=refill 'noise_overrides={}' seed=0 \\
        --out clip.mp4
    python -m experiments.render --flight results/ultrasonic --out flight.gif --fps 15

- A sweep cell (named like :mod:`experiments.export`: ``--key`` or ``--where`` axis values):
  the rover (``models/rover.xml`` with the cell's antenna layout) driving its path, posed
  from the cell's per-epoch truth (linear between epochs, wheels turned by the distance each
  travelled); the estimated pose as a red ghost: a translucent box 4 cm larger than the hull
  on every side (so it still shows when the estimate is within centimetres of the truth) and
  opaque red antennas joined by the layout's outline (its convex hull,
  :mod:`experiments.outline`), held from one estimate to the next (what a live display would
  show), drawn whenever the estimated position is finite (a red ball when only the heading
  is missing); heading arrows (black true, red estimated); the observed antennas of the
  current epoch (purple); the true (black) and estimated (red) tracks so far. The chase
  camera widens and shifts towards the estimate when it strays (up to 30 m), so the ghost
  stays in the frame; the top camera frames the whole path from straight above, with a
  ground grid over it and arrows and markers scaled up to stay visible. A cell without
  saved epochs is recomputed from the recorded spec, as ``experiments.export`` does.
- ``--flight``: the quadcopter (``models/quadcopter.xml``) flying its square from
  ``flight_series.csv`` of ``python -m experiments.ultrasonic``: the six receivers (blue, the
  trilateration triple brighter), range rays from each receiver towards the front
  transmitter as long as the measured range (blue gated, orange the raw range where it
  differs by more than 5 cm: a spike), and the Kalman-estimated transmitters as a red ghost.
  The CSV has no roll and pitch: the airframe is drawn level at the true yaw.

Rendering is offscreen, no display: ``MUJOCO_GL=osmesa`` (Debian ``libosmesa6``) or ``egl``;
when MUJOCO_GL is unset, :func:`render_cell`, :func:`render_flight` and the CLI pick osmesa if
libOSMesa is installed, else egl. MuJoCo reads the variable once, when it is first imported:
in a process that imported MuJoCo before (e.g. through ``sim``), set it yourself first.
Frame rate, size, playback speed (simulated seconds per clip second), start and length are
options; a progress bar runs while frames render. The format follows the file name: ``.mp4``
(H.264 through imageio-ffmpeg) or ``.gif``.
"""

from __future__ import annotations

import argparse
import ctypes.util
import itertools
import json
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

__all__ = ["MAX_FRAMES", "ClipOptions", "flight_frames", "main", "render_cell", "render_flight",
           "rover_frames", "write_clip"]

_GL_OK = ("osmesa", "egl")
#: Most frames one clip may have (an hour at 25 fps): a typo in speed fails fast instead.
MAX_FRAMES = 90_000


def _choose_gl() -> None:
    """MUJOCO_GL for offscreen rendering, unless set: osmesa when libOSMesa is installed,
    else egl. MuJoCo reads it once, when first imported."""
    if "MUJOCO_GL" not in os.environ and "mujoco" not in sys.modules:
        os.environ["MUJOCO_GL"] = "osmesa" if ctypes.util.find_library("OSMesa") else "egl"


@dataclass(frozen=True)
class ClipOptions:
    """What a clip looks like. fps (frames per clip second), width/height (pixels), speed
    (simulated seconds per clip second; None: the whole run in about 20 s), start_s (first
    simulated second), duration_s (simulated seconds; None: to the end), max_frames (None:
    all), camera ("chase" follows behind the platform, "top" looks down on the whole path)."""

    fps: float = 25.0
    width: int = 640
    height: int = 480
    speed: float | None = None
    start_s: float = 0.0
    duration_s: float | None = None
    max_frames: int | None = None
    camera: str = "chase"

    def __post_init__(self) -> None:
        for name in ("fps", "speed", "start_s", "duration_s"):
            v = getattr(self, name)
            if v is None and name in ("speed", "duration_s"):
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or v < 0 or (v == 0 and name != "start_s"):
                raise ValueError(f"{name}: must be a finite number > 0"
                                 f"{' (or >= 0)' if name == 'start_s' else ''}, got {v!r}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 16 <= v <= 4096:
                raise ValueError(f"{name}: must be an integer pixel count in [16, 4096], got {v!r}")
        if self.max_frames is not None and (isinstance(self.max_frames, bool) or not isinstance(
                self.max_frames, int) or self.max_frames < 1):
            raise ValueError(f"max_frames: must be a positive integer, got {self.max_frames!r}")
        if self.camera not in ("chase", "top"):
            raise ValueError(f"camera: must be 'chase' or 'top', got {self.camera!r}")

    def times(self, t0: float, t1: float) -> np.ndarray:
        """Simulated time of each frame within [t0, t1] (seconds)."""
        speed = self.speed or max((t1 - t0) / 20.0, 1e-9)
        a = t0 + self.start_s
        b = t1 if self.duration_s is None else min(t1, a + self.duration_s)
        if not b > a:
            raise ValueError(f"start_s: {self.start_s} s leaves nothing of the run "
                             f"({t1 - t0:.1f} s long)")
        n = math.floor((b - a) * self.fps / speed) + 1
        if self.max_frames is not None:
            n = min(n, self.max_frames)
        if n > MAX_FRAMES:
            raise ValueError(f"speed: {speed:g} s per clip second at {self.fps:g} fps gives {n} "
                             f"frames (limit {MAX_FRAMES}); raise speed or set duration_s / "
                             "max_frames")
        return a + np.arange(n) * speed / self.fps


# --------------------------------------------------------------------------- scene helpers
class _Scene:
    """Offscreen renderer plus decoration geoms added after each update_scene.

    near_m, far_m: the camera's clip distances (m). MuJoCo's default is 0.01 and 50 x the
    model's extent (1.8 m for the rover: 91 m), which clipped the whole scene away from a
    top camera 120 m above a 100 m square (black frames but the caption); a near plane far
    from the camera keeps the depth buffer fine enough for the lines drawn 5 mm above the
    ground (resolution ~ distance^2 / (near x 2^24))."""

    def __init__(self, model, opts: ClipOptions, near_m: float = 0.05, far_m: float = 300.0):
        import mujoco

        backend = os.environ.get("MUJOCO_GL", "").lower()
        if backend not in _GL_OK:
            raise RuntimeError(f"MUJOCO_GL={backend or '(unset)'}: offscreen rendering needs "
                               "osmesa (apt-get install libosmesa6) or egl; set it before MuJoCo "
                               "is imported, e.g. MUJOCO_GL=osmesa python -m experiments.render")
        self.mj = mujoco
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, opts.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, opts.height)
        model.vis.quality.shadowsize = 2048
        model.vis.headlight.ambient[:] = 0.45      # software GL: a bright, even headlight
        model.vis.headlight.diffuse[:] = 0.55
        model.vis.headlight.specular[:] = 0.1
        if not 0 < near_m < far_m:
            raise ValueError(f"near_m, far_m: need 0 < near < far, got {near_m!r}, {far_m!r}")
        model.vis.map.znear = near_m / model.stat.extent     # both relative to the extent
        model.vis.map.zfar = far_m / model.stat.extent
        self.model, self.data = model, mujoco.MjData(model)
        self.r = mujoco.Renderer(model, opts.height, opts.width, max_geom=4000)
        self.cam = mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FREE

    def close(self) -> None:
        self.r.close()

    def _geom(self, gtype, size, pos, mat, rgba):
        scn = self.r.scene
        if scn.ngeom >= scn.maxgeom:
            return None
        g = scn.geoms[scn.ngeom]
        self.mj.mjv_initGeom(g, gtype, np.asarray(size, float), np.asarray(pos, float),
                             np.asarray(mat, float).ravel(), np.asarray(rgba, np.float32))
        scn.ngeom += 1
        return g

    def box(self, pos, yaw, half, rgba):
        c, s = math.cos(yaw), math.sin(yaw)
        self._geom(self.mj.mjtGeom.mjGEOM_BOX, half, pos, [[c, -s, 0], [s, c, 0], [0, 0, 1]], rgba)

    def sphere(self, pos, r, rgba):
        self._geom(self.mj.mjtGeom.mjGEOM_SPHERE, [r, r, r], pos, np.eye(3), rgba)

    def connector(self, a, b, width, rgba, kind="capsule"):
        a, b = np.asarray(a, float), np.asarray(b, float)
        if not (np.isfinite(a).all() and np.isfinite(b).all()) or np.allclose(a, b):
            return
        t = {"capsule": self.mj.mjtGeom.mjGEOM_CAPSULE, "line": self.mj.mjtGeom.mjGEOM_LINE,
             "arrow": self.mj.mjtGeom.mjGEOM_ARROW}[kind]
        g = self._geom(t, [0, 0, 0], [0, 0, 0], np.eye(3), rgba)
        if g is not None:
            self.mj.mjv_connector(g, t, width, a, b)
            if kind == "arrow":    # MuJoCo draws an arrow half its size[2] long (measured)
                g.size[2] *= 2.0

    def polyline(self, xs, ys, z, rgba, width_px=2.0, max_segments=300):
        ok = np.isfinite(xs) & np.isfinite(ys)
        idx = np.flatnonzero(ok)
        if idx.size < 2:
            return
        idx = idx[np.unique(np.linspace(0, idx.size - 1, min(idx.size, max_segments + 1)
                                        ).round().astype(int))]
        for i, j in zip(idx[:-1], idx[1:]):
            self.connector([xs[i], ys[i], z], [xs[j], ys[j], z], width_px, rgba, "line")

    def set_free(self, joint: str, pos, yaw):
        adr = self.model.jnt_qposadr[self.model.joint(joint).id]
        self.data.qpos[adr:adr + 3] = pos
        self.data.qpos[adr + 3:adr + 7] = [math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]

    def frame(self, decorate, caption: list[str]) -> np.ndarray:
        self.mj.mj_kinematics(self.model, self.data)
        self.r.update_scene(self.data, camera=self.cam)
        decorate(self)
        img = self.r.render()
        return _caption(img, caption)


def _caption(img: np.ndarray, lines: list[str]) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    d = ImageDraw.Draw(im)
    size = max(10, img.shape[0] // 32)
    try:
        from PIL import ImageFont

        font = ImageFont.load_default(size=size)
    except (TypeError, OSError):
        font = None
    y = 4
    for line in lines:
        d.text((7, y + 1), line, fill=(0, 0, 0), font=font)
        d.text((6, y), line, fill=(255, 255, 255), font=font)
        y += size + 3
    return np.asarray(im)


def _interp(t: np.ndarray, tq: float, v: np.ndarray) -> float:
    return float(np.interp(tq, t, v))


def _hold(t: np.ndarray, tq: float) -> int:
    """Index of the last epoch at or before tq (sample-and-hold)."""
    return int(np.clip(np.searchsorted(t, tq, side="right") - 1, 0, len(t) - 1))


def _smooth_angle(t: np.ndarray, a: np.ndarray, half_window_s: float) -> np.ndarray:
    """Moving circular mean (for a camera that turns smoothly round the corners)."""
    z = np.exp(1j * np.nan_to_num(a))
    cs = np.concatenate([[0], np.cumsum(z)])
    lo = np.searchsorted(t, t - half_window_s)
    hi = np.searchsorted(t, t + half_window_s, side="right")
    return np.angle((cs[hi] - cs[lo]) / np.maximum(hi - lo, 1))


# --------------------------------------------------------------------------- rover
#: The free camera's vertical field of view (MuJoCo's default ``vis.global_.fovy``), degrees.
_FOVY_DEG = 45.0
#: The estimate's ghost: a translucent box this much larger than the hull on every side (m),
#: so it shows round the true hull when the estimate is within centimetres (a ghost the size
#: of the hull at the true pose is hidden inside the opaque hull), and opaque parts: its
#: antennas, their outline (the layout's convex hull) and its heading arrow.
_GHOST_MARGIN_M = 0.04
_GHOST_FILL = (0.95, 0.08, 0.08, 0.4)
_GHOST_SOLID = (0.9, 0.05, 0.05, 1.0)
#: Chase view: distance behind the platform (m), growing with the estimate's offset (capped
#: here, m) so that the ghost stays in the frame.
_CHASE_DISTANCE_M = 9.0
_CHASE_MAX_OFFSET_M = 30.0


def _nice_step(span: float) -> float:
    """A 1, 2 or 5 x 10^k grid spacing (m) giving 7 to 13 lines over ``span`` (m)."""
    raw = max(span, 1e-9) / 10.0
    e = 10.0 ** math.floor(math.log10(raw))
    return next(m * e for m in (1, 2, 5, 10) if m * e >= 0.75 * raw)


def _top_view(xs: np.ndarray, ys: np.ndarray, aspect: float) -> tuple[list[float], float]:
    """Look-at point (x, y, 0) and the distance (m) of a camera straight above that frames the
    finite points (xs, ys) (m) with a 15 % margin (the caption covers the top ~8 %), at least
    a 10 m square; ``aspect`` is width / height."""
    ok = np.isfinite(xs) & np.isfinite(ys)
    x, y = xs[ok], ys[ok]
    half_x = 0.575 * max(float(np.ptp(x)), 10.0)
    half_y = 0.575 * max(float(np.ptp(y)), 10.0)
    dist = max(half_y, half_x / aspect) / math.tan(math.radians(_FOVY_DEG / 2))
    return [0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max()), 0.0], dist


def _chase_offsets(t, tx, ty, ex, ey) -> tuple[np.ndarray, np.ndarray]:
    """Per-epoch offset (m) of the estimate from the truth, capped at _CHASE_MAX_OFFSET_M and
    0 where there is no estimate, averaged over +-8 s (a chase camera that widens smoothly
    when the estimate strays, instead of jumping at each epoch)."""
    dx, dy = np.nan_to_num(ex - tx), np.nan_to_num(ey - ty)
    n = np.hypot(dx, dy)
    f = np.where(n > _CHASE_MAX_OFFSET_M, _CHASE_MAX_OFFSET_M / np.maximum(n, 1e-300), 1.0)
    lo = np.searchsorted(t, t - 8.0)
    hi = np.searchsorted(t, t + 8.0, side="right")
    out = []
    for v in (dx * f, dy * f):
        cs = np.concatenate([[0.0], np.cumsum(v)])
        out.append((cs[hi] - cs[lo]) / np.maximum(hi - lo, 1))
    return out[0], out[1]


def _grid(s: _Scene, cx: float, cy: float, half: float, step: float) -> None:
    """Ground grid lines every ``step`` m within ``half`` m of (cx, cy), 5 mm above ground."""
    g0x, g0y = step * math.floor(cx / step), step * math.floor(cy / step)
    n = math.ceil(half / step)
    rgba = (0.45, 0.5, 0.44, 1)
    for i in range(-n, n + 1):
        d = i * step
        s.connector([g0x + d, g0y - n * step, 0.005], [g0x + d, g0y + n * step, 0.005], 1,
                    rgba, "line")
        s.connector([g0x - n * step, g0y + d, 0.005], [g0x + n * step, g0y + d, 0.005], 1,
                    rgba, "line")


@dataclass(frozen=True)
class _Platform:
    """What the rover's ghost needs: antenna layout (m, 2) in the body frame (m, origin at
    the reference point), its outline (convex-hull indices), antenna height (m), the hull's
    half sizes (3,) and centre height (m)."""

    body: np.ndarray
    outline: list[int]
    h_ant: float
    hull_half: np.ndarray
    hull_z: float


def _ghost(s: _Scene, pf: _Platform, ex: float, ey: float, eyaw: float, mk: float) -> None:
    """The estimate at pose (ex, ey, eyaw) (m, rad): a translucent red box enclosing the
    hull, red antennas joined by the layout's outline, a red heading arrow. Nothing without a
    position; a red ball at the position without a heading. ``mk``: marker size factor."""
    if not (math.isfinite(ex) and math.isfinite(ey)):
        return
    pt = math.sqrt(mk)
    if not math.isfinite(eyaw):
        s.sphere([ex, ey, pf.h_ant], 0.15 * pt, _GHOST_SOLID)
        return
    c, si = math.cos(eyaw), math.sin(eyaw)
    s.box([ex, ey, pf.hull_z], eyaw, pf.hull_half + _GHOST_MARGIN_M, _GHOST_FILL)
    pts = [[ex + c * bx - si * by, ey + si * bx + c * by, pf.h_ant] for bx, by in pf.body]
    ring = pf.outline + pf.outline[:1] if len(pf.outline) > 2 else pf.outline   # closed
    for i, j in itertools.pairwise(ring):
        s.connector(pts[i], pts[j], 0.02 * pt, _GHOST_SOLID)
    for p in pts:       # smaller than the true antennas (0.04 m), which show through
        s.sphere(p, 0.03 * pt, _GHOST_SOLID)
    s.connector([ex, ey, 1.05], [ex + 1.6 * mk * c, ey + 1.6 * mk * si, 1.05], 0.05 * mk,
                _GHOST_SOLID, "arrow")


def _rover_model(config: str):
    """The rover (or the path's vehicle) with the configuration's antennas, coloured for the
    clip: true antennas yellow, ground a light green-grey; and its ghost geometry."""
    from estimator.configuration import SensorConfig
    from experiments.outline import layout_outline
    from sim.rover import build_rover_model

    cfg = SensorConfig.load(config)
    model, _ = build_rover_model(cfg)
    for n in cfg.names:
        model.site_rgba[model.site(f"gps_{n}").id] = (0.95, 0.8, 0.1, 1)
    model.geom_rgba[model.geom("ground").id] = (0.6, 0.66, 0.58, 1)
    hull = model.geom("hull")
    body = cfg.body_positions[:, :2] - cfg.cg_body[:2]
    pf = _Platform(body, layout_outline(body), cfg.mount_height_m,
                   np.array(model.geom_size[hull.id]), float(model.geom_pos[hull.id][2]))
    return cfg, model, pf


def rover_frames(ep: pd.DataFrame, config: str, opts: ClipOptions) -> Iterator[np.ndarray]:
    """Frames (height, width, 3) uint8 of the rover replaying one cell's per-epoch table
    (columns of a sweep's ``epochs/<key>.parquet``: t, cg_x, cg_y, yaw, truth_cg_x,
    truth_cg_y, truth_yaw, optional obs_<name>_x/_y)."""
    need = ["t", "cg_x", "cg_y", "yaw", "truth_cg_x", "truth_cg_y", "truth_yaw"]
    missing = [c for c in need if c not in ep]
    if missing:
        raise ValueError(f"epochs: missing columns {missing} (a reference is needed to pose "
                         "the rover)")
    cfg, model, pf = _rover_model(config)
    t = ep["t"].to_numpy(float)
    tx, ty = ep["truth_cg_x"].to_numpy(float), ep["truth_cg_y"].to_numpy(float)
    tyaw = np.unwrap(ep["truth_yaw"].to_numpy(float))
    ex, ey, eyaw = (ep[c].to_numpy(float) for c in ("cg_x", "cg_y", "yaw"))
    top = opts.camera == "top"
    if top:
        centre, dist = _top_view(tx, ty, opts.width / opts.height)
        sc = _Scene(model, opts, near_m=0.5 * dist, far_m=2.0 * dist + 10.0)
    else:
        sc = _Scene(model, opts, near_m=0.5, far_m=300.0)
    m = sc.model
    wheels = []
    for side in ("left", "right"):
        b = m.body(f"wheel_{side}")
        wheels.append((f"wheel_{side}", float(m.body_pos[b.id][1]),
                       float(m.geom_size[m.geom(f"wheel_{side}").id][0])))
    # distance each wheel has rolled: forward motion +- yaw change x lateral offset
    ds = np.r_[0, np.hypot(np.diff(tx), np.diff(ty))]
    dpsi = np.r_[0, np.diff(tyaw)]
    rolled = {n: np.cumsum(ds - dpsi * y_off) / r for n, y_off, r in wheels}
    cam_yaw = np.unwrap(_smooth_angle(t, tyaw, 8.0))
    off_x, off_y = _chase_offsets(t, tx, ty, ex, ey)
    obs_names = [n for n in cfg.names if f"obs_{n}_x" in ep and f"obs_{n}_y" in ep]
    obs = {n: (ep[f"obs_{n}_x"].to_numpy(float), ep[f"obs_{n}_y"].to_numpy(float))
           for n in obs_names}
    # markers (arrows, balls) grow with the camera's distance, so they show from high up
    mk = max(1.0, dist / 15.0) if top else 1.0
    span = max(float(np.nanmax(np.abs(np.r_[np.ptp(tx), np.ptp(ty)]))), 10.0)
    try:
        for tq in opts.times(t[0], t[-1]):
            x, y = _interp(t, tq, tx), _interp(t, tq, ty)
            psi = _interp(t, tq, tyaw)
            sc.set_free("root", [x, y, 0.0], psi)
            for n, _, _ in wheels:
                sc.data.qpos[m.jnt_qposadr[m.joint(n).id]] = _interp(t, tq, rolled[n])
            k = _hold(t, tq)
            if top:
                sc.cam.lookat[:] = centre
                sc.cam.distance, sc.cam.elevation, sc.cam.azimuth = dist, -89.0, 90.0
            else:
                ox, oy = _interp(t, tq, off_x), _interp(t, tq, off_y)
                sc.cam.lookat[:] = [x + 0.5 * ox, y + 0.5 * oy, 0.5]
                sc.cam.distance = _CHASE_DISTANCE_M + math.hypot(ox, oy)
                sc.cam.elevation = -28.0
                sc.cam.azimuth = math.degrees(_interp(t, tq, cam_yaw)) + 35

            def decorate(s: _Scene, k=k, x=x, y=y, psi=psi) -> None:
                if top:
                    _grid(s, centre[0], centre[1], 0.6 * span, _nice_step(span))
                else:
                    _grid(s, x, y, 14.0, 2.0)
                s.polyline(tx[:k + 1], ty[:k + 1], 0.02, (0, 0, 0, 1))
                s.polyline(ex[:k + 1], ey[:k + 1], 0.03, (0.85, 0.1, 0.1, 1))
                s.connector([x, y, 0.9], [x + 1.6 * mk * math.cos(psi),
                                          y + 1.6 * mk * math.sin(psi), 0.9],
                            0.05 * mk, (0.05, 0.05, 0.05, 1), "arrow")
                for n in obs_names:
                    s.sphere([obs[n][0][k], obs[n][1][k], pf.h_ant], 0.07 * math.sqrt(mk),
                             (0.58, 0.4, 0.74, 1))
                _ghost(s, pf, ex[k], ey[k], eyaw[k], mk)

            err = math.hypot(ex[k] - tx[k], ey[k] - ty[k])
            eh = math.degrees(math.remainder(eyaw[k] - tyaw[k], 2 * math.pi))
            yield sc.frame(decorate, [
                (f"t = {tq:7.1f} s   red ghost: estimate (epoch {t[k]:.0f} s), yellow: true "
                 "antennas, purple: observed"),
                (f"CG error {err:.2f} m, heading error {eh:+.1f} deg" if math.isfinite(err)
                 and math.isfinite(eh) else "no estimate yet")])
    finally:
        sc.close()


# --------------------------------------------------------------------------- quadcopter
def flight_frames(series: pd.DataFrame, receivers: tuple[list[str], np.ndarray],
                  used: list[str], opts: ClipOptions) -> Iterator[np.ndarray]:
    """Frames of the quadcopter replaying ``flight_series.csv`` (true pose from the midpoint
    of the transmitters and ``yaw_true``), with receivers, range rays and the estimate."""
    from sim.quadcopter import load_model

    for c in ("t", "mid_true_x", "front_true_x", "yaw_true"):
        if c not in series:
            raise ValueError(f"flight series: missing column {c!r}")
    # clip planes round the cameras below (top 12 m above the square, chase 8.5 m away)
    sc = _Scene(load_model(), opts, *((5.0, 40.0) if opts.camera == "top" else (0.1, 100.0)))
    names, rec = receivers
    t = series["t"].to_numpy(float)
    col = lambda p: np.stack([series[f"{p}_{a}"].to_numpy(float) for a in "xyz"], 1)  # noqa: E731
    mid, front = col("mid_true"), col("front_true")
    yaw = np.unwrap(series["yaw_true"].to_numpy(float))
    est_f = col("front_kf") if "front_kf_x" in series else None
    est_m = col("mid_kf") if "mid_kf_x" in series else None
    raw = {n: series.get(f"range_raw_front_{n}") for n in names}
    gated = {n: series.get(f"range_robust_front_{n}") for n in names}
    centre = np.r_[np.nanmean(mid[:, :2], 0), 1.0]
    try:
        for tq in opts.times(t[0], t[-1]):
            p = np.array([_interp(t, tq, mid[:, a]) for a in range(3)])
            sc.set_free("root", p, _interp(t, tq, yaw))
            k = _hold(t, tq)
            if opts.camera == "chase":            # between the quadcopter and the receivers
                sc.cam.lookat[:] = 0.5 * p + 0.5 * np.r_[rec[:, :2].mean(0), 0.0]
                sc.cam.distance, sc.cam.elevation, sc.cam.azimuth = 8.5, -35.0, -60.0
            else:
                sc.cam.lookat[:] = centre
                sc.cam.distance, sc.cam.elevation, sc.cam.azimuth = 12.0, -89.0, 90.0

            def decorate(s: _Scene, k=k) -> None:
                s._geom(s.mj.mjtGeom.mjGEOM_PLANE, [40, 40, 0.5], [centre[0], centre[1], -0.03],
                        np.eye(3), (0.7, 0.74, 0.68, 1))
                s.polyline(front[:, 0], front[:, 1], front[0, 2], (0, 0, 0, 0.6), 1.5)
                f = front[k]
                for n, r in zip(names, rec):
                    on = n in used
                    s.box(r, 0.0, [0.06, 0.06, 0.03], (0.1, 0.35, 0.85, 1) if on
                          else (0.55, 0.65, 0.85, 1))
                    d = f - r
                    dn = float(np.linalg.norm(d))
                    if dn <= 0:
                        continue
                    g = float(gated[n].iloc[k]) if gated[n] is not None else np.nan
                    w = float(raw[n].iloc[k]) if raw[n] is not None else np.nan
                    if np.isfinite(g):
                        s.connector(r, r + d / dn * g, 0.012 if on else 0.006,
                                    (0.1, 0.45, 0.9, 0.9))
                    if np.isfinite(w) and not abs(w - g) <= 0.05:
                        s.connector(r, r + d / dn * w, 0.02, (1.0, 0.5, 0.05, 1))
                if est_f is not None and np.isfinite(est_f[k]).all():
                    rear = 2 * est_m[k] - est_f[k] if est_m is not None else est_f[k]
                    s.sphere(est_f[k], 0.05, (0.9, 0.1, 0.1, 0.8))
                    s.sphere(rear, 0.05, (0.9, 0.1, 0.1, 0.8))
                    s.connector(rear, est_f[k], 0.015, (0.9, 0.1, 0.1, 0.6))

            yield sc.frame(decorate, [(f"t = {tq:6.2f} s   blue: gated ranges, orange: raw "
                                       "where it differs"),
                                      "red: Kalman estimate of both transmitters"])
    finally:
        sc.close()


# --------------------------------------------------------------------------- output
def write_clip(frames: Iterator[np.ndarray], out: str | Path, fps: float, n_frames: int,
               progress: bool = True) -> Path:
    """Write frames to ``out`` (.mp4 H.264 via imageio-ffmpeg, or .gif); returns the path."""
    from tqdm import tqdm

    out = Path(out)
    suffix = out.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise ValueError(f"out: must end in .mp4 or .gif, got {out.name!r}")
    out.parent.mkdir(parents=True, exist_ok=True)
    bar = tqdm(frames, total=n_frames, unit="frame", desc=out.name, disable=not progress)
    if suffix == ".gif":
        from PIL import Image

        ims = [Image.fromarray(f).quantize(colors=128, method=Image.Quantize.MEDIANCUT)
               for f in bar]
        ims[0].save(out, save_all=True, append_images=ims[1:], duration=1000.0 / fps, loop=0)
        return out
    import imageio.v2 as imageio

    with imageio.get_writer(out, fps=fps, codec="libx264", quality=7, macro_block_size=2,
                            pixelformat="yuv420p") as w:
        for f in bar:
            w.append_data(f)
    return out


def _even(opts: ClipOptions, out: Path) -> ClipOptions:
    """H.264 in yuv420p needs even frame sizes."""
    if out.suffix.lower() != ".mp4" or (opts.width % 2 == 0 and opts.height % 2 == 0):
        return opts
    from dataclasses import replace

    return replace(opts, width=opts.width + opts.width % 2, height=opts.height + opts.height % 2)


def render_cell(results: str | Path, out: str | Path, *, key: str | None = None,
                where: dict | None = None, opts: ClipOptions = ClipOptions(),
                progress: bool = True) -> Path:
    """Render one cell of a sweep results folder (chosen by key or axis values) to ``out``."""
    _choose_gl()
    from experiments.export import _epochs
    from experiments.selection import find_cell

    results, out = Path(results), Path(out)
    opts = _even(opts, out)
    cell = find_cell(results, key, where)
    ep = _epochs(results, cell)
    t = ep["t"].to_numpy(float)
    n = len(opts.times(t[0], t[-1]))
    return write_clip(rover_frames(ep, _config_file(results, cell), opts), out, opts.fps, n,
                      progress)


def _config_file(results: Path, cell: pd.Series) -> str:
    """The cell's configuration as the sweep resolved it (a model named by path is labelled
    by its ``name``, which ``SensorConfig.load`` alone would not find); the label where the
    folder has no manifest."""
    from experiments.export import recorded_cell

    if not (results / "manifest.json").exists():
        return str(cell["config"])
    f = recorded_cell(results, str(cell["key"]))[1].file("config")
    return str(cell["config"]) if f is None else str(f)


def render_flight(ultrasonic: str | Path, out: str | Path, *, opts: ClipOptions = ClipOptions(),
                  progress: bool = True) -> Path:
    """Render the ultrasonic flight of ``<ultrasonic>/flight_series.csv`` to ``out``."""
    _choose_gl()
    from sim.ultrasonic import load_receivers

    ultrasonic, out = Path(ultrasonic), Path(out)
    opts = _even(opts, out)
    f = ultrasonic / "flight_series.csv"
    if not f.exists():
        raise ValueError(f"flight: {f} not found (run python -m experiments.ultrasonic first)")
    s = pd.read_csv(f)
    names, rec = load_receivers("flight")
    info = ultrasonic / "run_info.json"
    used = json.loads(info.read_text()).get("flight", {}).get("triple", []) if info.exists() else []
    t = s["t"].to_numpy(float)
    n = len(opts.times(t[0], t[-1]))
    return write_clip(flight_frames(s, (list(names), rec), used, opts), out, opts.fps, n,
                      progress)


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT such as 640x480, got {text!r}") from None
    return w, h


def main(argv: list[str] | None = None) -> int:
    _choose_gl()
    from experiments.cli import ArgumentParser
    from experiments.selection import parse_where

    p = ArgumentParser(
        prog="python -m experiments.render",
        description="Render a sweep cell (the rover, its estimate as a ghost) or the "
                    "ultrasonic flight (quadcopter, receivers, range rays) offscreen to MP4/GIF.",
        epilog="examples:\n  python -m experiments.render results/thesis --where path=square100 "
               "window=100 \\\n      technique=lc+dyn weighting=huff dyn_growth=refill "
               "'noise_overrides={}' seed=0 --out clip.mp4\n"
               "  python -m experiments.render --flight results/ultrasonic --out flight.gif "
               "--fps 15 --size 480x360",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", nargs="?", help="sweep results folder, e.g. results/thesis")
    p.add_argument("--key", help="the cell's key (see cells.parquet)")
    p.add_argument("--where", nargs="*", default=[], metavar="AXIS=VALUE",
                   help="select the cell by axis values, e.g. window=100 technique=lc seed=0")
    p.add_argument("--flight", metavar="DIR", help="render the ultrasonic flight of DIR "
                   "(flight_series.csv), e.g. --flight results/ultrasonic")
    p.add_argument("--out", required=True, help="output file, .mp4 or .gif, e.g. --out clip.mp4")
    p.add_argument("--fps", type=float, default=25.0, help="frames per second (default 25)")
    p.add_argument("--size", type=_size, default=(640, 480), metavar="WxH",
                   help="frame size in pixels (default 640x480)")
    p.add_argument("--speed", type=float, help="simulated seconds per clip second (default: "
                   "the whole run in about 20 s), e.g. --speed 50")
    p.add_argument("--start", type=float, default=0.0, metavar="S",
                   help="start this many simulated seconds into the run")
    p.add_argument("--duration", type=float, metavar="S", help="simulated seconds to render")
    p.add_argument("--frames", type=int, metavar="N", help="render at most N frames")
    p.add_argument("--camera", choices=("chase", "top"), default="chase",
                   help="chase: behind the platform (default); top: the whole path from above")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    if bool(args.flight) == bool(args.results):
        print("error: give a results folder (with --key/--where) or --flight DIR",
              file=sys.stderr)
        return 2
    try:
        opts = ClipOptions(fps=args.fps, width=args.size[0], height=args.size[1],
                           speed=args.speed, start_s=args.start, duration_s=args.duration,
                           max_frames=args.frames, camera=args.camera)
        if args.flight:
            path = render_flight(args.flight, args.out, opts=opts, progress=not args.quiet)
        else:
            path = render_cell(args.results, args.out, key=args.key,
                               where=parse_where(args.where), opts=opts,
                               progress=not args.quiet)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(path)
    return 0


if __name__ == "__main__":
    from experiments.cli import run as run_cli

    run_cli(main)
