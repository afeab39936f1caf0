"""F450-class quadcopter in MuJoCo: square flights with ultrasonic-transmitter truth, impulse tests.

Replaces the real flights of thesis 003 (003_691aa933e2e3c7e2.txt): a DJI F450 carrying two
ultrasonic transmitters 0.5 m apart, front and rear (Figure 3.3, Section 3.2.2), flown above
six ground receivers. The model is ``models/quadcopter.xml`` (physical values and their
sources are in its header comment); this module holds the flight controller, the path
reference, the truth logger and the impulse experiments of Section 3.3.

Controller (cascade, one update per ``1 / control_rate_hz``, ``mj_step(model, data, nstep)``
in between):

1. position -> acceleration: PD on the reference position/velocity plus the reference
   acceleration, plus compensation of the (known) linear drag;
2. acceleration -> attitude and collective thrust: the desired body z axis is the desired
   force direction (tilt limited), heading from the yaw reference (Lee, Leok, McClamroch 2010);
3. attitude -> body rates: proportional on the geometric attitude error;
4. rates -> torques: proportional on the rate error times the inertia, plus omega x I omega;
5. mixer: the 4 x 4 allocation matrix built from the rotor sites and actuator gears of the
   compiled model (thrust and reaction torque per rotor); thrusts outside the actuator range
   are saturated by MuJoCo's ctrlrange and *counted* (``meta["motor_saturation_fraction"]``).

Reference: the path's polyline with every corner replaced by a circular arc tangent to both
legs at ``target_radius_m`` from the corner (the target areas of 000 Section 4.9, the same
route semantics as the rover), flown at ``cruise_speed_mps`` with smooth (cosine, bounded
jerk) speed ramps of peak acceleration ``max_accel_mps2`` (default 0.5 m/s^2) from hover at
the start to hover at the end. The ``turning`` flag is the controller's own: True while the reference is on a corner arc.

Truth sampling: uneven intervals drawn uniformly (in whole physics steps) from
``sample_interval_s = (min, max)`` with the passed Generator; default max = 1 /
``path.sample_rate_hz`` (quad_square6: 0.1 s, the thesis's "maximum sampling interval is
roughly 0.1 seconds (data is not an evenly spaced time-series)", Section 3.2.2) and
min = max / 5. Sample times come from an integer step counter; positions are read after
``mj_kinematics``.

Impulse experiments (Section 3.3) and the command path
------------------------------------------------------
The thesis sent impulses through the radio's buddy-box channels into the F450's flight
controller and identified (Section 3.3.1-3.3.3)

- thrust -> altitude: ``K e^{-Td s} / (s (1 + Tp1 s)(1 + Tp2 s))``, Tp1 = 0.409 s,
  Tp2 = 0.423 s, Td = 0.659 s;
- pitch -> position: ``K e^{-Td s} / (s (1 + 2 zeta Tw s + (Tw s)^2))``, Tw = 5.44 s,
  zeta = 0.40, Td = 0.365 s;
- yaw rate -> heading: ``K e^{-Td s} / (s (1 + Tp1 s))``, Tp1 = 1.84 s, Td = 0.0044 s.

These are properties of the whole command chain (radio link, flight-controller input
shaping, airframe, ultrasonic post-processing); the thesis does not describe the flight
controller. We model each channel as a *stick channel* (:data:`STICK_CHANNELS`): a pure link
delay and a first-order input filter, in front of the physical loops. :func:`impulse_response`
drives the stick channel; the autonomous path flights command the loops directly (no stick
channel). What each identified constant comes from in this simulator:

- thrust: one pole is the vertical inflow damping (physical, ``m / drag_z`` = 0.42 s, see the
  XML), the other is the flight controller's throttle filter (0.41 s, chosen to match), the
  delay is the link delay 0.62 s (chosen) + 30 ms motor lag + 12 ms actuator delay, which a
  two-pole fit absorbs into Td (about 0.66 s in total);
- yaw rate: the yaw-rate loop is closed (time constant 1 / k_rate_yaw = 0.05 s) behind a
  1.80 s stick filter (chosen), so the fitted pole is the filter's (measured 1.80 s, thesis
  1.84 s) and the fitted delay is about the loop's 0.05 s (thesis 0.0044 s);
- pitch: the stick sets the tilt angle (attitude loop closed, position and velocity loops
  open); position then follows ``g / (s (s + drag_xy / m))`` behind the attitude loop and a
  0.33 s link delay (chosen near the thesis's 0.365 s). This plant has only real poles
  (drag 2.9 s, attitude loop ~0.05 s), so a ``second_order`` fit finds zeta > 1 (measured
  noise-free: zeta 3.7, Tw 0.40 s, Td 0.40 s, i.e. 2 zeta Tw = 2.9 s = the drag pole): the
  thesis's underdamped zeta = 0.40, Tw = 5.44 s is *not* reproduced. An underdamped
  response would need a closed velocity loop in the flight controller, which the thesis
  does not document; we keep the physical open loop instead.

Measured noise-free fits (:mod:`estimator.sysid`, 0.05 s grid, default impulses): thrust
Tp1 = Tp2 = 0.416 s, Td = 0.657 s, K = 4.116 m/s = m g / drag_z (thesis 0.409, 0.423,
0.659 s); yaw rate Tp1 = 1.80 s, Td = 0.046 s, K = 0.995. The thesis's gains (1856.4,
3425.9, 91.258) are in millimetres (degrees) per normalised stick unit and are not
comparable with ours (SI per fraction of hover thrust, rad, rad/s).

The chosen (non-physical) numbers are the stick-channel delays and filters; the physical
ones (motor lag, actuator delay, drag, inertia) are justified in the XML. Measured fits are
in ``tests/test_quadcopter.py`` and the README.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass
from pathlib import Path as FsPath
from typing import NamedTuple

import mujoco
import numpy as np
from scipy.ndimage import gaussian_filter1d

from estimator.configuration import MODELS_DIR
from sim.paths import Path, load_path
from sim.truth import Truth

__all__ = [
    "AXES",
    "MODEL_PATH",
    "SENSOR_NAMES",
    "STICK_CHANNELS",
    "Gains",
    "ImpulseResponse",
    "StickChannel",
    "impulse_response",
    "load_model",
    "reference_trajectory",
    "simulate_quadcopter",
]

MODEL_PATH = MODELS_DIR / "quadcopter.xml"
#: Truth sensor names: thesis transmitters T20 (front) and T21 (rear).
SENSOR_NAMES = ("front", "rear")
_TX_SITES = ("tx_front", "tx_rear")
_MOTORS = ("motor_fl", "motor_fr", "motor_rr", "motor_rl")
_BODY = "quad"
AXES = ("thrust", "pitch", "yaw_rate")
_G = 9.81


@dataclass(frozen=True)
class Gains:
    """Cascaded-controller gains (SI; rates in 1/s) and limits.

    Position loop: ``a = a_ref + kp * (p_ref - p) + kd * (v_ref - v)`` per axis (horizontal
    kp_xy, kd_xy; vertical kp_z, kd_z), tilt limited to ``max_tilt_rad``. Attitude loop:
    ``omega_des = -k_att * e_R`` (yaw component ``k_att_yaw``). Rate loop:
    ``torque = I * k_rate * (omega_des - omega) + omega x I omega`` (yaw ``k_rate_yaw``).
    ``yaw_ref_smoothing_s``: sigma (s) of the zero-lag Gaussian smoothing of the heading
    reference in ``yaw_mode="along_path"``.
    """

    control_rate_hz: float = 250.0
    kp_xy: float = 4.0
    kd_xy: float = 4.0
    kp_z: float = 9.0
    kd_z: float = 6.0
    k_att: float = 8.0
    k_att_yaw: float = 3.0
    k_rate: float = 20.0
    k_rate_yaw: float = 20.0
    max_tilt_rad: float = 0.5
    yaw_ref_smoothing_s: float = 0.3

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"gains.{k}: must be a finite number > 0, got {v!r}")


@dataclass(frozen=True)
class StickChannel:
    """Radio + flight-controller input path of one command channel (see module docstring).

    delay_s : pure link delay, seconds (rounded to whole controller periods).
    tau_s : first-order input filter time constant, seconds (0 = no filter).
    """

    delay_s: float
    tau_s: float

    def __post_init__(self) -> None:
        for k in ("delay_s", "tau_s"):
            v = getattr(self, k)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"channel.{k}: must be a finite number >= 0, got {v!r}")


#: Default stick channels, chosen so that identified constants are of the thesis's order
#: (Section 3.3; see the module docstring for what is physical and what is chosen).
STICK_CHANNELS: dict[str, StickChannel] = {
    "thrust": StickChannel(delay_s=0.62, tau_s=0.41),
    "pitch": StickChannel(delay_s=0.33, tau_s=0.0),
    "yaw_rate": StickChannel(delay_s=0.0, tau_s=1.80),
}

#: Default impulse per axis: (amplitude, pulse_s, units of u). Thrust: fraction of the hover
#: thrust; pitch: tilt angle (rad, positive accelerates towards +x); yaw rate: rad/s.
_IMPULSE_DEFAULTS = {"thrust": (0.2, 0.5), "pitch": (0.05, 0.5), "yaw_rate": (0.5, 1.0)}


# ------------------------------------------------------------------------------ model
def load_model(path: str | FsPath = MODEL_PATH) -> mujoco.MjModel:
    """Compile the quadcopter MJCF and apply its linear drag (custom numerics) as dof damping.

    The free joint's translational dofs are world-frame (damping ``drag_xy``, ``drag_xy``,
    ``drag_z``), its rotational dofs body-frame (``drag_rot``); see the XML header.
    """
    model = mujoco.MjModel.from_xml_path(str(path))
    drag = {n: float(model.numeric(n).data[0]) for n in ("drag_xy", "drag_z", "drag_rot")}
    adr = model.jnt_dofadr[model.joint("root").id]
    model.dof_damping[adr:adr + 6] = [drag["drag_xy"], drag["drag_xy"], drag["drag_z"],
                                      drag["drag_rot"], drag["drag_rot"], drag["drag_rot"]]
    return model


class _Plant:
    """Model, data and the quantities the controller reads by name."""

    def __init__(self, model_path: str | FsPath) -> None:
        self.xml_text = FsPath(model_path).read_text()
        self.model = load_model(model_path)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.body = m.body(_BODY).id
        self.mass = float(m.body_subtreemass[self.body])
        self.inertia = np.array(m.body_inertia[self.body], dtype=float)
        self.dt = float(m.opt.timestep)
        self.qadr = m.jnt_qposadr[m.joint("root").id]
        self.vadr = m.jnt_dofadr[m.joint("root").id]
        self.drag = np.array(m.dof_damping[self.vadr:self.vadr + 3], dtype=float)
        self.tx = np.array([m.site(s).id for s in _TX_SITES])
        self.act = np.array([m.actuator(a).id for a in _MOTORS])
        # allocation: [thrust, tau_x, tau_y, tau_z] (body) = A @ f, f = rotor thrusts (N)
        A = np.zeros((4, 4))
        for j, a in enumerate(self.act):
            site = m.actuator_trnid[a, 0]
            if m.site_bodyid[site] != self.body or not np.allclose(m.site_quat[site], [1, 0, 0, 0]):
                raise ValueError(f"model: rotor site of {_MOTORS[j]} must be an unrotated site "
                                 f"on body {_BODY!r}")
            g = m.actuator_gear[a]
            r = m.site_pos[site]
            A[0, j] = g[2]
            A[1:, j] = np.cross(r, g[:3]) + g[3:6]
        self.mixer = np.linalg.inv(A)
        self.fmax = np.array(m.actuator_ctrlrange[self.act, 1], dtype=float)
        self.fmin = np.array(m.actuator_ctrlrange[self.act, 0], dtype=float)
        self.hover_thrust = self.mass * _G

    def reset_hover(self, pos: np.ndarray, yaw: float) -> None:
        """Start in the air, level, at rest, motors and delay buffers at hover thrust."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[self.qadr:self.qadr + 3] = pos
        d.qpos[self.qadr + 3:self.qadr + 7] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        # rotor thrusts for hover thrust and zero torque; motor states and delay buffers too
        f = self.mixer @ np.array([self.hover_thrust, 0.0, 0.0, 0.0])
        for j, a in enumerate(self.act):
            d.ctrl[a] = f[j]
            d.act[m.actuator_actadr[a]] = f[j]
            nh = int(m.actuator_history[a, 0])
            mujoco.mj_initCtrlHistory(m, d, int(a), None, np.full((nh, 1), f[j]))
        mujoco.mj_forward(m, d)


class _Stick:
    """Discrete stick channel at the controller rate: delay line + exact first-order filter."""

    def __init__(self, channel: StickChannel, h: float) -> None:
        self.nd = round(channel.delay_s / h)
        self.buf = np.zeros(self.nd + 1)
        self.i = 0
        self.alpha = 1.0 - math.exp(-h / channel.tau_s) if channel.tau_s > 0 else 1.0
        self.y = 0.0

    def __call__(self, u: float) -> float:
        # ring buffer: write u, read the value written nd ticks ago
        self.buf[self.i] = u
        delayed = self.buf[(self.i - self.nd) % (self.nd + 1)]
        self.i = (self.i + 1) % (self.nd + 1)
        self.y += self.alpha * (delayed - self.y)
        return self.y


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3-vector cross product (np.cross costs ~30 us per call; this ~2 us)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def _quat_to_R(q: np.ndarray) -> np.ndarray:
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, q)
    return R.reshape(3, 3)


class _Controller:
    """Cascade of Section-level loops (see module docstring); one call = one update."""

    def __init__(self, plant: _Plant, gains: Gains) -> None:
        self.p = plant
        self.g = gains
        I = plant.inertia
        self.k_rate_I = I * np.array([gains.k_rate, gains.k_rate, gains.k_rate_yaw])
        self.k_att = np.array([gains.k_att, gains.k_att, gains.k_att_yaw])
        self.kp = np.array([gains.kp_xy, gains.kp_xy, gains.kp_z])
        self.kd = np.array([gains.kd_xy, gains.kd_xy, gains.kd_z])
        self.tan_tilt = math.tan(gains.max_tilt_rad)
        self.saturated = 0
        self.updates = 0

    def update(self, p_ref, v_ref, a_ref, yaw_ref, yaw_rate_ref, *, thrust_open=None,
               tilt_x_open=None, yaw_rate_open=None) -> None:
        """Compute and set the four rotor thrust commands.

        thrust_open : collective thrust as a fraction of hover *deviation* (altitude loop open).
        tilt_x_open : tilt (rad) about the heading's y axis replacing the x position/velocity
            loops (positive accelerates towards +x at heading 0).
        yaw_rate_open : body yaw-rate command (rad/s) replacing the heading loop.
        """
        pl, d = self.p, self.p.data
        q = d.qpos[pl.qadr:pl.qadr + 7]
        pos = q[:3]
        R = _quat_to_R(q[3:7])
        vel = d.qvel[pl.vadr:pl.vadr + 3]
        om = d.qvel[pl.vadr + 3:pl.vadr + 6]
        m = pl.mass
        # 1. position loop -> desired force (world), drag compensated
        acc = a_ref + self.kp * (p_ref - pos) + self.kd * (v_ref - vel)
        F = m * acc + pl.drag * vel
        F[2] += m * _G
        if tilt_x_open is not None:
            # x loops open: the force's x component sets the commanded tilt; the physical drag
            # acts uncompensated on the x motion
            F[0] = F[2] * math.tan(tilt_x_open)
        # tilt limit (horizontal force magnitude vs vertical)
        fh = math.hypot(F[0], F[1])
        lim = self.tan_tilt * max(F[2], 0.1 * m * _G)
        if fh > lim:
            F[0] *= lim / fh
            F[1] *= lim / fh
        F[2] = max(F[2], 0.1 * m * _G)
        # 2. desired attitude: b3 along F, heading yaw_ref
        b3 = F / math.sqrt(F @ F)
        c = np.array([math.cos(yaw_ref), math.sin(yaw_ref), 0.0])
        b2 = _cross(b3, c)
        b2 /= math.sqrt(b2 @ b2)
        b1 = _cross(b2, b3)
        Rd = np.array([b1, b2, b3]).T
        if thrust_open is None:
            T = float(F @ R[:, 2])
        else:
            T = pl.hover_thrust * (1.0 + thrust_open)
        # 3. attitude loop: e_R = 1/2 vee(Rd^T R - R^T Rd)
        E = Rd.T @ R
        E = E - E.T
        eR = 0.5 * np.array([E[2, 1], E[0, 2], E[1, 0]])
        om_des = -self.k_att * eR
        if yaw_rate_open is None:
            om_des[2] += yaw_rate_ref * R[2, 2]
        else:
            om_des[2] = yaw_rate_open
        # 4. rate loop
        Iom = pl.inertia * om
        tau = self.k_rate_I * (om_des - om) + _cross(om, Iom)
        # 5. mixer
        f = pl.mixer @ np.array([T, tau[0], tau[1], tau[2]])
        if np.any(f > pl.fmax) or np.any(f < pl.fmin):
            self.saturated += 1
        self.updates += 1
        d.ctrl[pl.act] = f


# -------------------------------------------------------------------------- reference
def _speed_profile(t: np.ndarray, L: float, v: float, a: float) -> tuple[np.ndarray, ...]:
    """Smooth rest-to-rest s(t), s'(t), s''(t) over length L (bounded jerk).

    Speed ramps as ``v/2 (1 - cos(pi t / ta))`` with ``ta = pi v / (2 a)`` (peak acceleration
    ``a``), cruises at ``v`` and ramps down symmetrically; a path too short for the cruise
    speed peaks at ``sqrt(2 a L / pi)``. Returns (s, sd, sdd, T) with T the total time.
    """
    if v * (math.pi * v / (2 * a)) > L:  # both ramps (v * ta / 2 each) exceed L
        v = math.sqrt(2 * a * L / math.pi)
    ta = math.pi * v / (2 * a)
    tc = (L - v * ta) / v
    T = 2 * ta + tc
    t = np.clip(t, 0.0, T)
    w = math.pi / ta
    td = T - t
    up, down = t < ta, t > ta + tc
    s = np.where(up, 0.5 * v * (t - np.sin(w * t) / w),
                 np.where(down, L - 0.5 * v * (td - np.sin(w * td) / w), 0.5 * v * ta + v * (t - ta)))
    sd = np.where(up, 0.5 * v * (1 - np.cos(w * t)), np.where(down, 0.5 * v * (1 - np.cos(w * td)), v))
    sdd = np.where(up, 0.5 * v * w * np.sin(w * t), np.where(down, -0.5 * v * w * np.sin(w * td), 0.0))
    return s, sd, sdd, T


def _route(path: Path, altitude_m: float | None) -> np.ndarray:
    V = path.polyline
    if V.shape[1] == 2:
        if altitude_m is None:
            raise ValueError(f"path.altitude_m: required for 2-D waypoints (path {path.name!r}), "
                             "got None")
        V = np.column_stack([V, np.full(V.shape[0], altitude_m)])
    return V


def _pieces(V: np.ndarray, r: float) -> list[tuple]:
    """Lines and corner arcs: ('line', P0, P1) / ('arc', O, R, a, n1, phi)."""
    pieces: list[tuple] = []
    start = V[0]
    k = V.shape[0]
    for i in range(1, k - 1):
        a = V[i] - V[i - 1]
        a /= np.linalg.norm(a)
        b = V[i + 1] - V[i]
        b /= np.linalg.norm(b)
        cphi = float(np.clip(a @ b, -1.0, 1.0))
        phi = math.acos(cphi)
        if phi < 1e-9:  # collinear: no arc
            continue
        if phi > math.pi - 1e-6:
            raise ValueError(f"path.waypoints[{i}]: the route reverses (180 deg turn); "
                             "a corner arc is undefined")
        P1 = V[i] - r * a
        pieces.append(("line", start, P1))
        n1 = b - cphi * a
        n1 /= np.linalg.norm(n1)
        R = r / math.tan(phi / 2)
        O = P1 + R * n1
        pieces.append(("arc", O, R, a, n1, phi))
        start = V[i] + r * b
    pieces.append(("line", start, V[-1]))
    return pieces


def _piece_len(pc: tuple) -> float:
    return float(np.linalg.norm(pc[2] - pc[1])) if pc[0] == "line" else pc[2] * pc[5]


def reference_trajectory(path: Path | str, t: np.ndarray, *, accel_mps2: float | None = None
                         ) -> dict[str, np.ndarray]:
    """Reference of a path flight at times ``t`` (s, from the start at rest).

    The polyline's corners are replaced by arcs tangent to both legs at ``target_radius_m``
    from the corner (000 Section 4.9 target areas); speed cruises at
    ``cruise_speed_mps`` and peak acceleration ``accel_mps2`` (default ``path.max_accel_mps2``
    or 0.5 m/s^2), smooth (cosine) ramps. 2-D waypoints fly at ``path.altitude_m``.

    Returns a dict of arrays: ``p, v, a`` (n, 3) m, m/s, m/s^2; ``yaw`` (n,) tangent heading,
    unwrapped, rad; ``yaw_rate`` (n,) rad/s; ``turning`` (n,) bool (on a corner arc);
    ``s`` (n,) arclength m; and the scalars ``duration`` (s) and ``length`` (m) as 0-d arrays.
    Raises ValueError if the lateral acceleration on an arc exceeds
    ``path.max_lateral_accel_mps2`` (default 2 m/s^2).
    """
    path = load_path(path)
    t = np.asarray(t, dtype=float)
    acc = accel_mps2 if accel_mps2 is not None else (path.max_accel_mps2 or 0.5)
    V = _route(path, path.altitude_m)
    pcs = _pieces(V, path.target_radius_m)
    lens = np.array([_piece_len(pc) for pc in pcs])
    starts = np.concatenate([[0.0], np.cumsum(lens)])
    L = float(starts[-1])
    vmax = path.cruise_speed_mps
    lat_lim = path.max_lateral_accel_mps2 or 2.0
    for pc in pcs:
        if pc[0] == "arc" and vmax**2 / pc[2] > lat_lim:
            raise ValueError(
                f"path.cruise_speed_mps: {vmax} m/s on a corner arc of radius {pc[2]:.3g} m "
                f"needs {vmax**2 / pc[2]:.3g} m/s^2 > max_lateral_accel_mps2 = {lat_lim}")
    s, sd, sdd, T = _speed_profile(t, L, vmax, acc)
    idx = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(pcs) - 1)
    n = t.shape[0]
    p = np.empty((n, 3))
    tan = np.empty((n, 3))
    curv = np.zeros((n, 3))  # curvature vector (1/m), points to the arc centre
    turning = np.zeros(n, dtype=bool)
    for j, pc in enumerate(pcs):
        sel = idx == j
        if not sel.any():
            continue
        u = s[sel] - starts[j]
        if pc[0] == "line":
            P0, P1 = pc[1], pc[2]
            d = (P1 - P0) / np.linalg.norm(P1 - P0)
            p[sel] = P0 + u[:, None] * d
            tan[sel] = d
        else:
            O, R, a, n1, _ = pc[1:]
            th = u / R
            c, sn = np.cos(th)[:, None], np.sin(th)[:, None]
            radial = -n1 * c + a * sn          # from the centre to the point, unit
            p[sel] = O + R * radial
            tan[sel] = a * c + n1 * sn
            curv[sel] = -radial / R
            turning[sel] = True
    v = sd[:, None] * tan
    a = sdd[:, None] * tan + (sd**2)[:, None] * curv
    yaw = np.unwrap(np.arctan2(tan[:, 1], tan[:, 0]))
    # d(yaw)/dt = sd * (t x kappa)_z / |t_xy|^2
    txy2 = tan[:, 0] ** 2 + tan[:, 1] ** 2
    cz = tan[:, 0] * curv[:, 1] - tan[:, 1] * curv[:, 0]
    yaw_rate = np.where(txy2 > 1e-12, sd * cz / np.maximum(txy2, 1e-12), 0.0)
    return {"p": p, "v": v, "a": a, "yaw": yaw, "yaw_rate": yaw_rate, "turning": turning,
            "s": s, "duration": np.array(T), "length": np.array(L)}


# ------------------------------------------------------------------------ simulation
def _sample_steps(rng: np.random.Generator, total_steps: int, dt: float,
                  interval: tuple[float, float]) -> np.ndarray:
    """Uneven sample steps: 0, then cumulative intervals uniform over whole steps."""
    lo, hi = interval
    kmin = max(1, math.ceil(lo / dt - 1e-9))
    kmax = math.floor(hi / dt + 1e-9)
    if kmax < kmin:
        raise ValueError(f"sample_interval_s: {interval} contains no whole physics step "
                         f"of {dt} s")
    n_draw = total_steps // kmin + 2
    k = rng.integers(kmin, kmax + 1, size=n_draw)
    steps = np.concatenate([[0], np.cumsum(k)])
    return steps[steps <= total_steps]


def _check_interval(sample_interval_s, path: Path) -> tuple[float, float]:
    if sample_interval_s is None:
        hi = 1.0 / path.sample_rate_hz
        return (hi / 5.0, hi)
    try:
        lo, hi = (float(x) for x in sample_interval_s)
    except (TypeError, ValueError):
        raise ValueError(f"sample_interval_s: expected (min, max) seconds, got "
                         f"{sample_interval_s!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"sample_interval_s: need 0 < min <= max, got {sample_interval_s!r}")
    return (lo, hi)


def simulate_quadcopter(path: Path | str = "quad_square6", *, seed: int = 0,
                        rng: np.random.Generator | None = None,
                        sample_interval_s: tuple[float, float] | None = None,
                        cache_dir: str | FsPath | bool | None = None,
                        yaw_mode: str = "fixed", yaw_rad: float = 0.0,
                        gains: Gains | None = None, hover_after_s: float = 2.0,
                        duration_s: float | None = None,
                        model_path: str | FsPath = MODEL_PATH) -> Truth:
    """Fly ``path`` and log the transmitters' truth at uneven ultrasonic sample times.

    Parameters
    ----------
    path : a :class:`~sim.paths.Path` or a name in models/paths (2-D waypoints need
        ``altitude_m``). The flight starts hovering at the first waypoint, follows the
        reference of :func:`reference_trajectory` and hovers ``hover_after_s`` at the end.
    seed, rng : sample intervals are drawn from ``rng`` if given, else from
        ``numpy.random.default_rng(seed)``. The dynamics are deterministic.
    sample_interval_s : (min, max) seconds between truth samples (whole physics steps, drawn
        uniformly); default (0.2, 1) / ``path.sample_rate_hz`` (thesis 003 Section 3.2.2:
        intervals up to about 0.1 s).
    cache_dir : a directory: the Truth is cached there by a hash of everything that
        determines it (:mod:`sim.cache`); ``True``: the default ``results/cache/truth``;
        None or False: no cache (the default, so a plain call writes no files; note that
        ``simulate_rover`` caches by default). Ignored (no cache) when ``rng`` is given: a
        Generator's state is not part of the key.
    yaw_mode : "fixed" holds heading ``yaw_rad``; "along_path" turns the nose (front
        transmitter) along the reference tangent, rotating through the corner arcs.
    duration_s : simulate only the first ``duration_s`` seconds (partial path; tests).

    Returns
    -------
    Truth with ``sensor_names = ("front", "rear")``, ``sensor_positions`` (n, 2, 3) world
    transmitter positions, ``cg`` (n, 3) body CG, ``yaw`` (n,) heading of body x, ``speed``
    (n,) horizontal speed, ``yaw_rate`` (n,) world-z angular rate, ``turning`` (n,) the
    controller's corner-arc flag. ``meta`` records parameters, versions and the measured
    control quality (``motor_saturation_fraction``).
    """
    path = load_path(path)
    gains = gains if gains is not None else Gains()
    if yaw_mode not in ("fixed", "along_path"):
        raise ValueError(f"yaw_mode: expected 'fixed' or 'along_path', got {yaw_mode!r}")
    if not math.isfinite(yaw_rad):
        raise ValueError(f"yaw_rad: must be finite, got {yaw_rad!r}")
    if not (math.isfinite(hover_after_s) and hover_after_s >= 0):
        raise ValueError(f"hover_after_s: must be a finite number >= 0, got {hover_after_s!r}")
    if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s: must be a finite number > 0, got {duration_s!r}")
    interval = _check_interval(sample_interval_s, path)
    params = {"sample_interval_s": list(interval), "yaw_mode": yaw_mode, "yaw_rad": yaw_rad,
              "gains": asdict(gains), "hover_after_s": hover_after_s, "duration_s": duration_s}

    def compute() -> Truth:
        return _simulate(path, rng if rng is not None else np.random.default_rng(seed),
                         interval, yaw_mode, yaw_rad, gains, hover_after_s, duration_s,
                         model_path, params, seed if rng is None else None)

    if cache_dir is None or cache_dir is False or rng is not None:
        return compute()
    from sim.cache import DEFAULT_CACHE_DIR, cached, truth_key

    if cache_dir is True:
        cache_dir = DEFAULT_CACHE_DIR

    key = truth_key(simulator="quadcopter", model_xml=FsPath(model_path).read_text(),
                    path=path, params=params, seed=seed)
    return cached(key, compute, cache_dir)


def _simulate(path, rng, interval, yaw_mode, yaw_rad, gains, hover_after_s, duration_s,
              model_path, params, seed) -> Truth:
    plant = _Plant(model_path)
    m, d = plant.model, plant.data
    dt = plant.dt
    nctrl = round(1.0 / (gains.control_rate_hz * dt))
    if nctrl < 1 or abs(nctrl * dt * gains.control_rate_hz - 1.0) > 1e-9:
        raise ValueError(f"gains.control_rate_hz: {gains.control_rate_hz} Hz is not the physics "
                         f"rate {1 / dt:g} Hz divided by a whole number")
    h = nctrl * dt
    T_ref = float(reference_trajectory(path, np.zeros(1))["duration"])
    T_total = T_ref + hover_after_s if duration_s is None else duration_s
    n_ticks = math.ceil(T_total / h - 1e-9)
    total_steps = n_ticks * nctrl
    ref = reference_trajectory(path, np.arange(n_ticks) * h)
    if yaw_mode == "fixed":
        yaw_ref = np.full(n_ticks, yaw_rad)
        yaw_rate_ref = np.zeros(n_ticks)
    else:
        # the tangent heading turns at v / R from the first instant of an arc; the yaw
        # authority (reaction torque only) cannot follow a rate step, so the planned (known
        # in advance) heading is smoothed without lag by a Gaussian of sigma
        # gains.yaw_ref_smoothing_s; its peak yaw acceleration is about
        # (v / R) / (sigma sqrt(2 pi)).
        yaw_ref = gaussian_filter1d(ref["yaw"], gains.yaw_ref_smoothing_s / h, mode="nearest")
        yaw_rate_ref = np.gradient(yaw_ref, h)
    plant.reset_hover(ref["p"][0], float(yaw_ref[0]))
    ctrl = _Controller(plant, gains)
    steps = _sample_steps(rng, total_steps, dt, interval)
    ns = steps.shape[0]
    tx = np.empty((ns, 2, 3))
    cg = np.empty((ns, 3))
    yaw = np.empty(ns)
    speed = np.empty(ns)
    yaw_rate = np.empty(ns)
    turning = np.zeros(ns, dtype=bool)
    body, vadr = plant.body, plant.vadr

    def log(i: int, tick: int) -> None:
        mujoco.mj_kinematics(m, d)
        tx[i] = d.site_xpos[plant.tx]
        cg[i] = d.xipos[body]
        R = d.xmat[body]
        yaw[i] = math.atan2(R[3], R[0])
        v = d.qvel[vadr:vadr + 3]
        speed[i] = math.hypot(v[0], v[1])
        om = d.qvel[vadr + 3:vadr + 6]
        yaw_rate[i] = R[6] * om[0] + R[7] * om[1] + R[8] * om[2]
        turning[i] = ref["turning"][min(tick, n_ticks - 1)]

    i = 0
    log(0, 0)
    i = 1
    cur = 0
    p_r, v_r, a_r = ref["p"], ref["v"], ref["a"]
    for tick in range(n_ticks):
        ctrl.update(p_r[tick], v_r[tick], a_r[tick], float(yaw_ref[tick]),
                    float(yaw_rate_ref[tick]))
        end = cur + nctrl
        while i < ns and steps[i] <= end:
            k = int(steps[i]) - cur
            if k > 0:
                mujoco.mj_step(m, d, k)
                cur += k
            log(i, tick)
            i += 1
        if cur < end:
            mujoco.mj_step(m, d, end - cur)
            cur = end
    t = steps * dt
    yaw = (yaw + math.pi) % (2 * math.pi) - math.pi
    yaw[yaw == -math.pi] = math.pi
    meta = {
        "model": "quadcopter", "model_file": str(model_path),
        "model_xml_sha256": hashlib.sha256(plant.xml_text.encode()).hexdigest(),
        "path": path.to_dict(), "seed": seed, "params": params,
        "timestep_s": dt, "control_period_s": h,
        "mass_kg": plant.mass, "drag_Nspm": plant.drag.tolist(),
        "reference_duration_s": T_ref, "simulated_s": total_steps * dt,
        "motor_saturation_fraction": ctrl.saturated / max(ctrl.updates, 1),
        "versions": {"mujoco": mujoco.__version__, "numpy": np.__version__},
    }
    return Truth(t=t, sensor_positions=tx, sensor_names=SENSOR_NAMES, cg=cg, yaw=yaw,
                 speed=speed, yaw_rate=yaw_rate, turning=turning, meta=meta)


# ------------------------------------------------------------------- impulse responses
class ImpulseResponse(NamedTuple):
    """(t, u, y) on a uniform grid; unpacks as a 3-tuple.

    t : (n,) s, starting at 0; the pulse starts at ``pre_s``.
    u : (n,) the stick input as sent (before the stick channel): thrust as a fraction of the
        hover thrust, pitch tilt in rad, yaw-rate command in rad/s.
    y : (n,) output deviation from hover: altitude (m), x position (m), heading (rad,
        unwrapped).
    """

    t: np.ndarray
    u: np.ndarray
    y: np.ndarray


def impulse_response(axis: str, *, duration_s: float = 8.0, pre_s: float = 1.0,
                     amplitude: float | None = None, pulse_s: float | None = None,
                     sample_interval_s: float = 0.05, channel: StickChannel | None = None,
                     altitude_m: float = 2.5, gains: Gains | None = None,
                     model_path: str | FsPath = MODEL_PATH) -> ImpulseResponse:
    """Open-loop impulse response of one command channel from hover (thesis 003 Section 3.3).

    Only the tested loop is opened; the others stay closed:

    - ``"thrust"``: collective thrust = hover thrust * (1 + stick), altitude loop open;
      horizontal position and heading held. y = altitude change (m). Form
      ``K e^{-Td s} / (s (1 + Tp1 s)(1 + Tp2 s))`` (Section 3.3.1).
    - ``"pitch"``: the stick sets the tilt about the body y axis (heading 0, positive
      accelerates towards +x); x position and velocity loops open, attitude, y and altitude
      held. y = x displacement (m). Form ``K e^{-Td s} / (s (1 + 2 zeta Tw s + (Tw s)^2))``
      (Section 3.3.2); see the module docstring for why zeta >= 1 here.
    - ``"yaw_rate"``: the stick commands the body yaw rate, heading loop open. y = heading
      change (rad, unwrapped). Form ``K e^{-Td s} / (s (1 + Tp1 s))`` (Section 3.3.3).

    The stick passes through ``channel`` (default :data:`STICK_CHANNELS[axis]`). Defaults:
    thrust 0.2 x hover for 0.5 s; pitch 0.05 rad for 0.5 s (Section 3.3.2: "impulse command
    of duration 0.5s"); yaw rate 0.5 rad/s for 1.0 s (Section 3.3.3: "roughly 1s"). The grid
    interval 0.05 s is the thesis's resampling interval (Appendix C, ``Sampling Interval``);
    the thesis's window is 1 s before and 4 s after the impulse, the default 8 s lets the
    1.8 s yaw pole settle.
    """
    if axis not in AXES:
        raise ValueError(f"axis: expected one of {AXES}, got {axis!r}")
    amp0, pulse0 = _IMPULSE_DEFAULTS[axis]
    amplitude = amp0 if amplitude is None else amplitude
    pulse_s = pulse0 if pulse_s is None else pulse_s
    for name, v, lo in (("duration_s", duration_s, 0.0), ("pulse_s", pulse_s, 0.0),
                        ("sample_interval_s", sample_interval_s, 0.0)):
        if not (math.isfinite(v) and v > lo):
            raise ValueError(f"{name}: must be a finite number > 0, got {v!r}")
    if not (math.isfinite(pre_s) and pre_s >= 0):
        raise ValueError(f"pre_s: must be a finite number >= 0, got {pre_s!r}")
    if not math.isfinite(amplitude):
        raise ValueError(f"amplitude: must be finite, got {amplitude!r}")
    if not math.isfinite(altitude_m):
        raise ValueError(f"altitude_m: must be finite, got {altitude_m!r}")
    gains = gains if gains is not None else Gains()
    channel = channel if channel is not None else STICK_CHANNELS[axis]
    plant = _Plant(model_path)
    m, d = plant.model, plant.data
    dt = plant.dt
    nctrl = round(1.0 / (gains.control_rate_hz * dt))
    h = nctrl * dt
    grid_steps = sample_interval_s / dt
    k_grid = round(grid_steps)
    if k_grid < 1 or abs(k_grid - grid_steps) > 1e-6:
        raise ValueError(f"sample_interval_s: {sample_interval_s} s is not a whole number of "
                         f"physics steps ({dt} s)")
    # the returned u is the input held on the grid (zero-order hold), so the pulse edges must
    # fall on grid points and on controller updates, or u would misstate what was applied
    for name, edge in (("pre_s", pre_s), ("pre_s + pulse_s", pre_s + pulse_s)):
        for period, what in ((sample_interval_s, "sample_interval_s"), (h, "control period")):
            q = edge / period
            if abs(q - round(q)) > 1e-6:
                raise ValueError(f"{name}: {edge} s is not a whole multiple of the {what} "
                                 f"({period:g} s); the pulse edges must be grid points")
    n = math.floor(duration_s / sample_interval_s + 1e-9) + 1
    total_steps = (n - 1) * k_grid
    n_ticks = math.ceil(total_steps / nctrl) + 1
    p0 = np.array([0.0, 0.0, altitude_m])
    plant.reset_hover(p0, 0.0)
    ctrl = _Controller(plant, gains)
    stick = _Stick(channel, h)
    zero3 = np.zeros(3)
    t_tick = np.arange(n_ticks) * h
    u_tick = np.where((t_tick >= pre_s - 1e-9) & (t_tick < pre_s + pulse_s - 1e-9),
                      amplitude, 0.0)
    y = np.empty(n)
    qadr = plant.qadr
    heading = 0.0
    last_yaw = 0.0

    def output() -> float:
        nonlocal heading, last_yaw
        q = d.qpos[qadr:qadr + 7]
        if axis == "thrust":
            return float(q[2] - p0[2])
        if axis == "pitch":
            return float(q[0] - p0[0])
        w, x, yq, z = q[3:7]
        yw = math.atan2(2 * (w * z + x * yq), 1 - 2 * (yq * yq + z * z))
        heading += (yw - last_yaw + math.pi) % (2 * math.pi) - math.pi
        last_yaw = yw
        return heading

    cur = 0
    j = 0
    for tick in range(n_ticks):
        s = stick(float(u_tick[tick]))
        kw = {"thrust": {"thrust_open": s}, "pitch": {"tilt_x_open": s},
              "yaw_rate": {"yaw_rate_open": s}}[axis]
        ctrl.update(p0, zero3, zero3, 0.0, 0.0, **kw)
        end = cur + nctrl
        while j < n and j * k_grid <= end:
            k = j * k_grid - cur
            if k > 0:
                mujoco.mj_step(m, d, k)
                cur += k
            y[j] = output()
            j += 1
        if j >= n:
            break
        if cur < end:
            mujoco.mj_step(m, d, end - cur)
            cur = end
        if axis == "yaw_rate":
            output()  # keep the heading unwrapping continuous between grid points
    t = np.arange(n) * sample_interval_s
    u = np.where((t >= pre_s - 1e-9) & (t < pre_s + pulse_s - 1e-9), amplitude, 0.0)
    return ImpulseResponse(t=t, u=u, y=y)
