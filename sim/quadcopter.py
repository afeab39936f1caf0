"""F450-class quadcopter in MuJoCo: square flights with ultrasonic-transmitter truth, impulse tests.

Replaces the real flights of thesis 003 (003_691aa933e2e3c7e2.txt): a DJI F450 carrying two
ultrasonic transmitters 0.5 m apart, front and rear (Figure 3.3, Section 3.2.2), flown above
six ground receivers. The model is ``models/quadcopter.xml`` (physical values and their
sources are in its header comment); this module holds the flight controller, the path
reference, the truth logger and the impulse experiments of Section 3.3.

Controller (cascade, one update per ``1 / control_rate_hz``, ``mj_step(model, data, nstep)``
in between):

1. position -> acceleration: PD on the reference position/velocity plus the reference
   acceleration, plus compensation of the (known) linear drag (its moment is fed forward in
   step 4);
2. acceleration -> attitude and collective thrust: the desired body z axis is the desired
   force direction (tilt limited), heading from the yaw reference (Lee, Leok, McClamroch 2010);
3. attitude -> body rates: proportional on the geometric attitude error;
4. rates -> torques: proportional on the rate error times the inertia, plus omega x I omega,
   minus the rotor drag's moment about the CG (path flights only);
5. mixer: the 4 x 4 allocation matrix built from the rotor sites and actuator gears of the
   compiled model (thrust and reaction torque per rotor); thrusts outside the actuator range
   are saturated by MuJoCo's ctrlrange and *counted* (``meta["motor_saturation_fraction"]``).

Reference: the path's polyline with every corner replaced by a circular arc tangent to both
legs at ``target_radius_m`` from the corner (the target areas of 000 Section 4.9, the same
route semantics as the rover), flown at ``cruise_speed_mps`` with smooth (cosine, bounded
jerk) speed ramps of peak acceleration ``max_accel_mps2`` (default 0.5 m/s^2) from hover at
the start to hover at the end. The ``turning`` flag is the controller's own: True while the
reference is on a corner arc.

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
- pitch (``pitch_mode="rate"``, the default): the stick sets the pitch *rate* (the flight
  controller's self-levelling is off on pitch; x position and velocity loops open) behind a
  0.33 s link delay (chosen near the thesis's 0.365 s). The rotor drag acts in the rotor
  plane, h = 4 cm above the CG (XML), so a forward speed v also pitches the nose up by the
  moment ``-h drag_xy v``; the P rate loop lets it, and the speed feeds back into the tilt.
  Linearised (:func:`pitch_chain`), the slow pair is to first order
  ``s^2 + (drag_xy / m) s + g drag_xy h / (I k_rate)``: underdamped, with
  ``2 zeta / Tw ~ drag_xy / m`` (the drag is its only damping). Measured noise-free fit:
  Tw 1.21 s, zeta 0.21, Td 0.378 s (chain: 1.21 s, 0.20, 0.380 s). Rate mode is chosen because
  the thesis's fitted model keeps accelerating for the whole 4 s after its 0.5 s impulse: a
  stick that sets the tilt cannot do that (the tilt returns with the stick), a stick that sets
  the rate leaves the tilt in place. The thesis's Tw = 5.44 s with zeta = 0.40 is *not*
  reproduced: it needs ``drag_xy / m ~ 2 zeta / Tw = 0.15 1/s`` and h = 4.7 mm, outside the
  F450 ranges of :data:`F450_RANGES` (which give Tw 0.59-2.9 s, zeta 0.09-0.44); with those
  values the simulator reproduces the thesis's numbers (``experiments.identification``,
  :func:`~experiments.identification.pitch_evidence`, which also shows that the thesis's own 5
  s window does not determine Tw and zeta).
- pitch, ``pitch_mode="angle"``: the stick sets the tilt angle (attitude loop closed):
  only real poles (drag, the drag moment against the attitude loop, attitude and rate
  loops), so a ``second_order`` fit finds zeta > 1 (measured noise-free: zeta 3.3,
  Tw 0.36 s, Td 0.40 s).

Measured noise-free fits (:mod:`estimator.sysid`, 0.05 s grid, default impulses): thrust
Tp1 = Tp2 = 0.416 s, Td = 0.657 s, K = 4.116 m/s = m g / drag_z (thesis 0.409, 0.423,
0.659 s); yaw rate Tp1 = 1.80 s, Td = 0.046 s, K = 0.995; pitch (rate mode) as above,
K = 14.30 m/s per rad/s (chain: k_rate I / (drag_xy h) = 14.29). The thesis's gains
(1856.4, 3425.9, 91.258) are in millimetres (degrees) per normalised stick unit and are not
comparable with ours (SI per fraction of hover thrust, rad/s).

The chosen (non-physical) numbers are the stick-channel delays and filters and the pitch
stick's mode; the physical ones (motor lag, actuator delay, drag, rotor height, inertia) are
justified in the XML. The path flights' autopilot feeds forward the rotor drag's force and
moment (it knows the model); the stick experiments' hobby flight controller does not.
:func:`simulator_constants` gives every chain constant that maps onto a thesis parameter;
:func:`constants_matched_to_thesis` lists those chosen to reproduce a published value.
:func:`impulse_flight` flies the same impulse experiments logged like a flight (uneven
sample times, transmitter truth) for the thesis's processing chain
(``experiments.identification_chain``).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path as FsPath
from typing import NamedTuple

import mujoco
import numpy as np
from scipy.ndimage import gaussian_filter1d

from estimator._checks import check_fields, check_real
from estimator.configuration import MODELS_DIR
from sim.paths import Path, load_path
from sim.truth import Truth

__all__ = [
    "AXES",
    "F450_RANGES",
    "MODEL_PATH",
    "PITCH_MODES",
    "SENSOR_NAMES",
    "STICK_CHANNELS",
    "Gains",
    "ImpulseFlight",
    "ImpulseResponse",
    "PitchChain",
    "StickChannel",
    "constants_matched_to_thesis",
    "impulse_flight",
    "impulse_response",
    "load_model",
    "model_variant",
    "pitch_chain",
    "pitch_chain_of",
    "reference_trajectory",
    "simulate_quadcopter",
    "simulator_constants",
]

MODEL_PATH = MODELS_DIR / "quadcopter.xml"
#: Truth sensor names: thesis transmitters T20 (front) and T21 (rear).
SENSOR_NAMES = ("front", "rear")
_TX_SITES = ("tx_front", "tx_rear")
_MOTORS = ("motor_fl", "motor_fr", "motor_rr", "motor_rl")
_DRAG_ACTUATORS = ("drag_x", "drag_y")
_ROTOR_PLANE = "rotor_plane"
_DRAG_NUMERICS = ("drag_xy", "drag_z", "drag_rot")
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
        check_fields(self, (f.name for f in fields(self)), prefix="gains.")


@dataclass(frozen=True)
class StickChannel:
    """Radio + flight-controller input path of one command channel (see module docstring).

    delay_s : pure link delay, seconds (rounded to whole controller periods).
    tau_s : first-order input filter time constant, seconds (0 = no filter).
    """

    delay_s: float
    tau_s: float

    def __post_init__(self) -> None:
        check_fields(self, ("delay_s", "tau_s"), prefix="channel.", lo_open=False)


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
#: Flight-controller modes of the pitch stick: "rate" (the stick commands the pitch rate,
#: self-levelling off) or "angle" (the stick commands the tilt angle).
PITCH_MODES = ("rate", "angle")
#: Ranges of the physical constants that shape the rate-mode pitch response, for an F450
#: of this build (models/quadcopter.xml has the defaults and their reasoning):
#: ``drag_xy_per_kg`` rotor drag / mass, 1/s (measured 0.3-0.5 1/s on small quadrotors,
#: Faessler, Franchi, Scaramuzza 2018); ``rotor_height_m`` rotor hubs above the CG (props
#: ~3.5 cm above the arms, CG 0.5-1.5 cm below them, battery / boom placement); ``inertia_yy``
#: kg m^2 (the motors alone give 0.0091, frame and battery 0.001-0.003, the 0.5 m
#: transmitter boom up to 0.003 more); ``k_rate`` 1/s, the rate loop's gain (crossover):
#: with the 30 ms motor lag, the 12 ms delay and half the 4 ms control period its phase
#: margin is 48 deg at 20 (the default), 24 deg at 40.
F450_RANGES: dict[str, tuple[float, float]] = {
    "drag_xy_per_kg": (0.3, 0.5),
    "rotor_height_m": (0.02, 0.05),
    "inertia_yy": (0.010, 0.015),
    "k_rate": (10.0, 40.0),
}
#: Default pitch impulse per mode (amplitude, pulse_s): rate 0.1 rad/s for 0.5 s leaves the
#: same 0.05 rad tilt as the angle impulse commands.
_PITCH_DEFAULTS = {"rate": (0.1, 0.5), "angle": (0.05, 0.5)}


# ------------------------------------------------------------------------------ model
def load_model(path: str | FsPath = MODEL_PATH) -> mujoco.MjModel:
    """Compile the quadcopter MJCF and apply its linear drag (custom numerics, see the XML).

    ``drag_xy`` (N s/m) becomes the damping of the ``drag_x`` / ``drag_y`` site actuators: the
    rotor drag, a force in the rotor plane at the ``rotor_plane`` site (body x and y), which
    also pitches / rolls the body since that site is above the CG. ``drag_z`` (N s/m, world
    z) and ``drag_rot`` (N m s/rad, body rotations) are free-joint dof damping.
    """
    model = mujoco.MjModel.from_xml_path(str(path))
    drag = {n: float(model.numeric(n).data[0]) for n in _DRAG_NUMERICS}
    adr = model.jnt_dofadr[model.joint("root").id]
    model.dof_damping[adr:adr + 6] = [0.0, 0.0, drag["drag_z"],
                                      drag["drag_rot"], drag["drag_rot"], drag["drag_rot"]]
    for name in _DRAG_ACTUATORS:
        model.actuator(name).biasprm[2] = -drag["drag_xy"]
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
        # translational drag (N s/m) per world axis, for the controller's drag compensation:
        # the rotor drag acts in the body's x-y plane, equal to world x-y for small tilts
        self.c_xy = float(-m.actuator(_DRAG_ACTUATORS[0]).biasprm[2])
        rp = m.site(_ROTOR_PLANE)
        if rp.bodyid[0] != self.body or not np.allclose(rp.pos[:2], 0.0):
            raise ValueError(f"model: site {_ROTOR_PLANE!r} must be on body {_BODY!r} on its "
                             f"z axis, got position {rp.pos.tolist()}")
        #: height (m) of the rotor plane's centre above the CG, where the rotor drag acts
        self.rotor_height = float(rp.pos[2])
        self.drag = np.array([-m.actuator(_DRAG_ACTUATORS[0]).biasprm[2],
                              -m.actuator(_DRAG_ACTUATORS[1]).biasprm[2],
                              m.dof_damping[self.vadr + 2]], dtype=float)
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

    def __init__(self, plant: _Plant, gains: Gains, *, drag_moment_ff: bool) -> None:
        self.p = plant
        self.g = gains
        # feedforward of the rotor drag's moment about the CG (the autopilot of the path
        # flights knows the model, as it knows the drag force); the stick experiments model
        # the thesis's hobby flight controller, which does not
        self.drag_moment_ff = drag_moment_ff
        I = plant.inertia
        self.k_rate_I = I * np.array([gains.k_rate, gains.k_rate, gains.k_rate_yaw])
        self.k_att = np.array([gains.k_att, gains.k_att, gains.k_att_yaw])
        self.kp = np.array([gains.kp_xy, gains.kp_xy, gains.kp_z])
        self.kd = np.array([gains.kd_xy, gains.kd_xy, gains.kd_z])
        self.tan_tilt = math.tan(gains.max_tilt_rad)
        self.saturated = 0
        self.updates = 0

    def update(self, p_ref, v_ref, a_ref, yaw_ref, yaw_rate_ref, *, thrust_open=None,
               tilt_x_open=None, pitch_rate_open=None, yaw_rate_open=None) -> None:
        """Compute and set the four rotor thrust commands.

        thrust_open : collective thrust as a fraction of hover *deviation* (altitude loop open).
        tilt_x_open : tilt (rad) about the heading's y axis replacing the x position/velocity
            loops (positive accelerates towards +x at heading 0).
        pitch_rate_open : body pitch-rate command (rad/s, about body y; positive tilts the
            thrust towards +x at heading 0) replacing the x position/velocity loops *and* the
            pitch angle loop (rate mode, self-levelling off on pitch).
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
        elif pitch_rate_open is not None:
            # x loops open and no pitch angle loop: the desired attitude keeps the present
            # x tilt of the thrust axis (so the pitch error is zero and only roll and heading
            # are held); the pitch rate is commanded below
            F[0] = F[2] * R[0, 2] / R[2, 2]
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
        if pitch_rate_open is not None:
            om_des[1] = pitch_rate_open
        if yaw_rate_open is None:
            om_des[2] += yaw_rate_ref * R[2, 2]
        else:
            om_des[2] = yaw_rate_open
        # 4. rate loop
        Iom = pl.inertia * om
        tau = self.k_rate_I * (om_des - om) + _cross(om, Iom)
        if self.drag_moment_ff:
            # the rotor drag -c_xy (u, w) at r = (0, 0, h), (u, w) the body x / y velocity of
            # the rotor plane's centre, has the moment r x F = c_xy h (w, -u, 0); cancel it
            h = pl.rotor_height
            u = R[0, 0] * vel[0] + R[1, 0] * vel[1] + R[2, 0] * vel[2] + h * om[1]
            w = R[0, 1] * vel[0] + R[1, 1] * vel[1] + R[2, 1] * vel[2] - h * om[0]
            tau[0] -= pl.c_xy * h * w
            tau[1] += pl.c_xy * h * u
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
                 np.where(down, L - 0.5 * v * (td - np.sin(w * td) / w),
                          0.5 * v * ta + v * (t - ta)))
    sd = np.where(up, 0.5 * v * (1 - np.cos(w * t)),
                  np.where(down, 0.5 * v * (1 - np.cos(w * td)), v))
    sdd = np.where(up, 0.5 * v * w * np.sin(w * t),
                   np.where(down, -0.5 * v * w * np.sin(w * td), 0.0))
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
    return _check_pair(sample_interval_s)


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
    check_real(yaw_rad, "yaw_rad")
    check_real(hover_after_s, "hover_after_s", lo=0.0)
    if duration_s is not None:
        check_real(duration_s, "duration_s", lo=0.0, lo_open=True)
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
    ctrl = _Controller(plant, gains, drag_moment_ff=True)
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
        hover thrust, pitch rate in rad/s (or tilt in rad, angle mode), yaw rate in rad/s.
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
                     pitch_mode: str = "rate",
                     model_path: str | FsPath = MODEL_PATH) -> ImpulseResponse:
    """Open-loop impulse response of one command channel from hover (thesis 003 Section 3.3).

    Only the tested loop is opened; the others stay closed:

    - ``"thrust"``: collective thrust = hover thrust * (1 + stick), altitude loop open;
      horizontal position and heading held. y = altitude change (m). Form
      ``K e^{-Td s} / (s (1 + Tp1 s)(1 + Tp2 s))`` (Section 3.3.1).
    - ``"pitch"``: ``pitch_mode="rate"`` (default): the stick sets the body pitch rate
      (rad/s, positive tilts towards +x at heading 0), pitch angle loop off;
      ``pitch_mode="angle"``: the stick sets the tilt (rad). Either way the x position and
      velocity loops are open, roll, heading, y and altitude held. y = x displacement (m).
      Form ``K e^{-Td s} / (s (1 + 2 zeta Tw s + (Tw s)^2))`` (Section 3.3.2); see the module
      docstring for the poles of each mode.
    - ``"yaw_rate"``: the stick commands the body yaw rate, heading loop open. y = heading
      change (rad, unwrapped). Form ``K e^{-Td s} / (s (1 + Tp1 s))`` (Section 3.3.3).

    The stick passes through ``channel`` (default :data:`STICK_CHANNELS[axis]`). Defaults:
    thrust 0.2 x hover for 0.5 s; pitch 0.1 rad/s (rate mode) or 0.05 rad (angle mode) for
    0.5 s (Section 3.3.2: "impulse command of duration 0.5s"); yaw rate 0.5 rad/s for 1.0 s
    (Section 3.3.3: "roughly 1s"). The grid
    interval 0.05 s is the thesis's resampling interval (Appendix C, ``Sampling Interval``);
    the thesis's window is 1 s before and 4 s after the impulse, the default 8 s lets the
    1.8 s yaw pole settle.
    """
    amplitude, pulse_s = _impulse_setup(axis, pitch_mode, amplitude, pulse_s, duration_s,
                                        pre_s, altitude_m)
    check_real(sample_interval_s, "sample_interval_s", lo=0.0, lo_open=True)
    gains = gains if gains is not None else Gains()
    channel = channel if channel is not None else STICK_CHANNELS[axis]
    plant = _Plant(model_path)
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
    _check_edges(pre_s, pulse_s, ((sample_interval_s, "sample_interval_s"),
                                  (h, "control period")))
    n = math.floor(duration_s / sample_interval_s + 1e-9) + 1
    steps = np.arange(n) * k_grid
    p0 = np.array([0.0, 0.0, altitude_m])
    y = np.empty(n)
    out = _Output(plant, axis, p0)

    def sample(j: int) -> None:
        y[j] = out()

    _fly_impulse(plant, gains, channel, axis, pitch_mode, amplitude, pre_s, pulse_s, p0,
                 steps, sample, out)
    t = np.arange(n) * sample_interval_s
    u = np.where((t >= pre_s - 1e-9) & (t < pre_s + pulse_s - 1e-9), amplitude, 0.0)
    return ImpulseResponse(t=t, u=u, y=y)


def _impulse_setup(axis, pitch_mode, amplitude, pulse_s, duration_s, pre_s, altitude_m):
    """Checks shared by the impulse experiments; returns the (default-filled) amplitude and
    pulse length."""
    if axis not in AXES:
        raise ValueError(f"axis: expected one of {AXES}, got {axis!r}")
    if pitch_mode not in PITCH_MODES:
        raise ValueError(f"pitch_mode: expected one of {PITCH_MODES}, got {pitch_mode!r}")
    amp0, pulse0 = _PITCH_DEFAULTS[pitch_mode] if axis == "pitch" else _IMPULSE_DEFAULTS[axis]
    amplitude = amp0 if amplitude is None else amplitude
    pulse_s = pulse0 if pulse_s is None else pulse_s
    for name, v in (("duration_s", duration_s), ("pulse_s", pulse_s)):
        check_real(v, name, lo=0.0, lo_open=True)
    check_real(pre_s, "pre_s", lo=0.0)
    check_real(amplitude, "amplitude")
    check_real(altitude_m, "altitude_m")
    return amplitude, pulse_s


def _check_edges(pre_s: float, pulse_s: float, periods) -> None:
    """The pulse edges must be whole multiples of each ``(period, what)``."""
    for name, edge in (("pre_s", pre_s), ("pre_s + pulse_s", pre_s + pulse_s)):
        for period, what in periods:
            q = edge / period
            if abs(q - round(q)) > 1e-6:
                raise ValueError(f"{name}: {edge} s is not a whole multiple of the {what} "
                                 f"({period:g} s); the pulse edges must be grid points")


class _Output:
    """The impulse experiment's output from the state: altitude change (thrust), x
    displacement (pitch) or the unwrapped heading change (yaw_rate; call it at least every
    controller tick so the unwrapping stays continuous)."""

    def __init__(self, plant: _Plant, axis: str, p0: np.ndarray) -> None:
        self.d, self.qadr, self.axis, self.p0 = plant.data, plant.qadr, axis, p0
        self.heading = 0.0
        self.last_yaw = 0.0

    def __call__(self) -> float:
        q = self.d.qpos[self.qadr:self.qadr + 7]
        if self.axis == "thrust":
            return float(q[2] - self.p0[2])
        if self.axis == "pitch":
            return float(q[0] - self.p0[0])
        return self.unwrapped_heading()

    def unwrapped_heading(self) -> float:
        q = self.d.qpos[self.qadr:self.qadr + 7]
        w, x, yq, z = q[3:7]
        yw = math.atan2(2 * (w * z + x * yq), 1 - 2 * (yq * yq + z * z))
        self.heading += (yw - self.last_yaw + math.pi) % (2 * math.pi) - math.pi
        self.last_yaw = yw
        return self.heading


def _fly_impulse(plant: _Plant, gains: Gains, channel: StickChannel, axis: str,
                 pitch_mode: str, amplitude: float, pre_s: float, pulse_s: float,
                 p0: np.ndarray, steps: np.ndarray, sample, out: _Output) -> None:
    """Fly one impulse experiment from hover at ``p0``: one controller update per tick with
    the stick through ``channel``; ``sample(j)`` is called when the physics has reached step
    ``steps[j]`` (increasing whole steps from 0), ``out.unwrapped_heading()`` once per tick
    (yaw only)."""
    m, d = plant.model, plant.data
    nctrl = round(1.0 / (gains.control_rate_hz * plant.dt))
    h = nctrl * plant.dt
    n = steps.shape[0]
    n_ticks = math.ceil(int(steps[-1]) / nctrl) + 1
    plant.reset_hover(p0, 0.0)
    ctrl = _Controller(plant, gains, drag_moment_ff=False)
    stick = _Stick(channel, h)
    zero3 = np.zeros(3)
    t_tick = np.arange(n_ticks) * h
    u_tick = np.where((t_tick >= pre_s - 1e-9) & (t_tick < pre_s + pulse_s - 1e-9),
                      amplitude, 0.0)
    pitch_kw = "pitch_rate_open" if pitch_mode == "rate" else "tilt_x_open"
    cur = 0
    j = 0
    for tick in range(n_ticks):
        s = stick(float(u_tick[tick]))
        kw = {"thrust": {"thrust_open": s}, "pitch": {pitch_kw: s},
              "yaw_rate": {"yaw_rate_open": s}}[axis]
        ctrl.update(p0, zero3, zero3, 0.0, 0.0, **kw)
        end = cur + nctrl
        while j < n and steps[j] <= end:
            k = int(steps[j]) - cur
            if k > 0:
                mujoco.mj_step(m, d, k)
                cur += k
            sample(j)
            j += 1
        if j >= n:
            break
        if cur < end:
            mujoco.mj_step(m, d, end - cur)
            cur = end
        if axis == "yaw_rate":
            out.unwrapped_heading()  # keep the heading unwrapping continuous between samples


class ImpulseFlight(NamedTuple):
    """An impulse experiment logged like a flight (:func:`impulse_flight`).

    t : (n,) s, uneven sample times from 0; the pulse starts at ``pre_s``.
    u : (n,) the stick as sent (before the stick channel) at each sample time.
    sensor_positions : (n, 2, 3) m, world positions of the transmitters ("front" = T20,
        "rear" = T21), read after ``mj_kinematics``.
    y : (n,) the truth output of :func:`impulse_response` at these times (altitude change,
        x displacement of the body origin, unwrapped heading change).
    pre_s, pulse_s, amplitude : the pulse as applied.
    """

    t: np.ndarray
    u: np.ndarray
    sensor_positions: np.ndarray
    y: np.ndarray
    pre_s: float
    pulse_s: float
    amplitude: float


def impulse_flight(axis: str, rng: np.random.Generator, *, duration_s: float = 17.0,
                   pre_s: float = 10.0, amplitude: float | None = None,
                   pulse_s: float | None = None,
                   sample_interval_s: tuple[float, float] = (0.03, 0.10),
                   channel: StickChannel | None = None, altitude_m: float = 2.5,
                   gains: Gains | None = None, pitch_mode: str = "rate",
                   model_path: str | FsPath = MODEL_PATH) -> ImpulseFlight:
    """The experiment of :func:`impulse_response`, logged at uneven ultrasonic sample times
    with the transmitters' truth, for the thesis's processing chain (003 Sections 3.2-3.3,
    Appendix C: ranges -> Filters 1/2 -> CMD -> Kalman -> resampling).

    Same plant, controller, stick channel and defaults as :func:`impulse_response` (with the
    same sample times both give the same ``y`` bit for bit, tested). Sample intervals are
    drawn from ``rng`` uniformly over whole physics steps in ``sample_interval_s`` (default
    0.03-0.10 s, :class:`sim.ultrasonic.UltrasonicNoiseModel`'s ``min/max_interval_s``:
    Section 3.2.2 "maximum sampling interval is roughly 0.1 seconds"). The default hover
    before the pulse (10 s) covers Appendix C's 40-sample lead-in and lets its Kalman filter
    settle; the thesis's impulse came 86.7 s into a flight.
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng: expected numpy.random.Generator, got {type(rng).__name__}")  # noqa: TRY004 (DESIGN: ValueError)
    amplitude, pulse_s = _impulse_setup(axis, pitch_mode, amplitude, pulse_s, duration_s,
                                        pre_s, altitude_m)
    gains = gains if gains is not None else Gains()
    channel = channel if channel is not None else STICK_CHANNELS[axis]
    plant = _Plant(model_path)
    dt = plant.dt
    h = round(1.0 / (gains.control_rate_hz * dt)) * dt
    _check_edges(pre_s, pulse_s, ((h, "control period"),))
    interval = _check_pair(sample_interval_s)
    steps = _sample_steps(rng, round(duration_s / dt), dt, interval)
    n = steps.shape[0]
    p0 = np.array([0.0, 0.0, altitude_m])
    tx = np.empty((n, 2, 3))
    y = np.empty(n)
    out = _Output(plant, axis, p0)
    m, d = plant.model, plant.data

    def sample(j: int) -> None:
        y[j] = out()
        mujoco.mj_kinematics(m, d)
        tx[j] = d.site_xpos[plant.tx]

    _fly_impulse(plant, gains, channel, axis, pitch_mode, amplitude, pre_s, pulse_s, p0,
                 steps, sample, out)
    t = steps * dt
    u = np.where((t >= pre_s - 1e-9) & (t < pre_s + pulse_s - 1e-9), amplitude, 0.0)
    return ImpulseFlight(t=t, u=u, sensor_positions=tx, y=y, pre_s=float(pre_s),
                         pulse_s=float(pulse_s), amplitude=float(amplitude))


def _check_pair(sample_interval_s) -> tuple[float, float]:
    """``sample_interval_s`` as (min, max) seconds, 0 < min <= max, finite."""
    try:
        lo, hi = (float(x) for x in sample_interval_s)
    except (TypeError, ValueError):
        raise ValueError(f"sample_interval_s: expected (min, max) seconds, got "
                         f"{sample_interval_s!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"sample_interval_s: need 0 < min <= max, got {sample_interval_s!r}")
    return (lo, hi)


# ------------------------------------------------- linearised chains (Section 3.3 constants)
class PitchChain(NamedTuple):
    """The linearised pitch stick -> x position chain about hover (:func:`pitch_chain`).

    poles : (4,) complex, 1/s, of x velocity (the position integrator left out), slowest first.
    K : steady x velocity per unit stick: m/s per rad/s (rate mode) or per rad (angle mode);
        ``inf`` if the chain has a second integrator (rate mode without a drag moment).
    Tw, zeta : the second-order factor ``1 + 2 zeta Tw s + (Tw s)^2`` of the two slowest poles
        (``Tw = 1 / sqrt(p1 p2)``, ``2 zeta Tw = -(1/p1 + 1/p2)``; zeta >= 1 for real poles).
    Td : link delay plus ``-sum 1/p`` over the other (fast) poles, the delay the thesis's form
        folds them into (first order).
    lag : ``Td + 2 zeta Tw``, the ramp asymptote's lag of the whole chain.
    A, B : (4, 4), (4,) the state-space model ``x' = A x + B u(t - delay_s)`` of the states
        ``(theta, q, alpha, v)`` (see :func:`pitch_chain`), for simulating it.
    """

    poles: np.ndarray
    K: float
    Tw: float
    zeta: float
    Td: float
    lag: float
    A: np.ndarray
    B: np.ndarray


def pitch_chain(mode: str = "rate", *, mass_kg: float, inertia_yy: float, drag_xy: float,
                rotor_height_m: float, k_rate: float, k_att: float, motor_lag_s: float,
                delay_s: float, g: float = _G) -> PitchChain:
    """Pitch stick -> x velocity of the simulated chain, linearised about hover (Section 3.3.2).

    States: tilt theta (rad, positive accelerates towards +x), pitch rate q, the rate loop's
    angular acceleration command after the first-order motor lag ``motor_lag_s``, x velocity
    v. The rotor drag ``-drag_xy (v + h q)`` acts at the rotor plane, ``h = rotor_height_m``
    above the CG (models/quadcopter.xml), so it also pitches the body by ``-h`` times itself:

        theta' = q,   v' = g theta - (drag_xy / m)(v + h q),
        q' = alpha - (drag_xy h / I)(v + h q),   alpha' = (k_rate (q_cmd - q) - alpha) / T_m,

    with ``q_cmd`` = the stick (``mode="rate"``) or ``k_att (stick - theta)`` (``"angle"``).
    Every argument is a real number within generous physical bounds (mass 1e-3..1e4 kg,
    inertia 1e-6..1e4 kg m^2, drag 0..1e4 N s/m, |h| <= 10 m, gains 1e-3..1e4 1/s, motor lag
    1e-6..10 s, delay 0..1e3 s); outside them ValueError names it.
    The actuator delay (12 ms) and the control period are left out (measured against MuJoCo:
    <= 1 % of the peak response, ``tests/test_quadcopter.py``). Without the motor lag the
    characteristic polynomial is ``s^3 + (k + c h^2/I + c/m) s^2 + k c/m s + g c h / I`` in
    rate mode (``c = drag_xy``, ``k = k_rate``; angle mode adds ``k k_att (s + c/m)``). For
    ``k`` well above the slow frequency the rate-mode slow pair is
    ``s^2 + (c/m - w^2/k) s + w^2`` with ``w^2 = g c h / (I k)``: underdamped, stiffened by
    the drag's moment, damped by the drag alone (less the rate loop's finite gain; the motor
    lag removes more).
    """
    if mode not in PITCH_MODES:
        raise ValueError(f"mode: expected one of {PITCH_MODES}, got {mode!r}")
    # generous physical bounds (SI): beyond them the eigenvalues of A lose every digit
    m = check_real(mass_kg, "mass_kg", lo=1e-3, hi=1e4)
    iyy = check_real(inertia_yy, "inertia_yy", lo=1e-6, hi=1e4)
    c = check_real(drag_xy, "drag_xy", lo=0.0, hi=1e4)
    h = check_real(rotor_height_m, "rotor_height_m", lo=-10.0, hi=10.0)
    k = check_real(k_rate, "k_rate", lo=1e-3, hi=1e4)
    ka = check_real(k_att, "k_att", lo=1e-3, hi=1e4)
    tm = check_real(motor_lag_s, "motor_lag_s", lo=1e-6, hi=10.0)
    d = check_real(delay_s, "delay_s", lo=0.0, hi=1e3)
    g = check_real(g, "g", lo=1e-3, hi=1e3)
    # x = [theta, q, alpha, v], input u (the stick after the link delay)
    A = np.array([[0.0, 1.0, 0.0, 0.0],
                  [0.0, -c * h * h / iyy, 1.0, -c * h / iyy],
                  [0.0, -k / tm, -1.0 / tm, 0.0],
                  [g, -c * h / m, 0.0, -c / m]])
    B = np.array([0.0, 0.0, k / tm, 0.0])
    if mode == "angle":
        A[2, 0] -= k * ka / tm
        B = B * ka
    poles = np.linalg.eigvals(A)
    poles = poles[np.argsort(np.abs(poles), kind="stable")]
    if np.min(np.abs(poles)) < 1e-12 * max(1.0, np.max(np.abs(poles))):
        K = math.inf
    else:
        K = float(-(np.linalg.solve(A, B))[3])
    p1, p2 = poles[0], poles[1]
    Tw = float(1.0 / np.sqrt((p1 * p2).real)) if (p1 * p2).real > 0 else math.nan
    two_zeta_tw = float(-(1.0 / p1 + 1.0 / p2).real) if math.isfinite(Tw) else math.nan
    Td = d + float(np.sum(-1.0 / poles[2:]).real)
    return PitchChain(poles=poles, K=K, Tw=Tw, zeta=two_zeta_tw / (2.0 * Tw), Td=Td,
                      lag=Td + two_zeta_tw, A=A, B=B)


def pitch_chain_of(model: mujoco.MjModel, *, mode: str = "rate", gains: Gains | None = None,
                   channel: StickChannel | None = None) -> PitchChain:
    """:func:`pitch_chain` with every constant read by name from a compiled ``model``
    (:func:`load_model`: mass and inertia of body ``quad``, ``drag_xy``, the ``rotor_plane``
    site's height, the motors' lag) and from ``gains`` / ``channel`` (defaults
    :class:`Gains`, :data:`STICK_CHANNELS` ``["pitch"]``)."""
    gains = gains if gains is not None else Gains()
    channel = channel if channel is not None else STICK_CHANNELS["pitch"]
    body = model.body(_BODY)
    return pitch_chain(mode, mass_kg=float(body.mass[0]), inertia_yy=float(body.inertia[1]),
                       drag_xy=float(model.numeric("drag_xy").data[0]),
                       rotor_height_m=float(model.site(_ROTOR_PLANE).pos[2]),
                       k_rate=gains.k_rate, k_att=gains.k_att,
                       motor_lag_s=float(model.actuator(_MOTORS[0]).dynprm[0]),
                       delay_s=channel.delay_s, g=-float(model.opt.gravity[2]))


def simulator_constants(*, pitch_mode: str = "rate", gains: Gains | None = None,
                        model_path: str | FsPath = MODEL_PATH
                        ) -> dict[str, dict[str, tuple[float, str]]]:
    """The simulated chain's own constants that map onto the thesis's parameters (3.3).

    ``{axis: {param: (value, how)}}`` for the forms of :data:`AXES` (``K``, the time
    constants, ``Td`` and the total ``lag``), read from the compiled model by name (mass,
    inertia, drag, rotor height, motor lag, actuator delay), :class:`Gains` and
    :data:`STICK_CHANNELS`. Parameters with no single counterpart in the chain are left out.

    Thrust and yaw: the total lag (ramp asymptote ``K (t - lag)``) adds up along the chain:
    the open thrust path adds the motor lag and actuator delay; a closed proportional loop
    adds only its own ``D'(0)`` (rate loop ``I / (k I + d)``), the motor lag and actuator
    delay inside it do not add (to first order; their effect in the yaw loop is
    ``d (tau_m + tau_a) / (k I + d)`` ~ 2e-4 s). Pitch: :func:`pitch_chain_of`.
    """
    if pitch_mode not in PITCH_MODES:
        raise ValueError(f"pitch_mode: expected one of {PITCH_MODES}, got {pitch_mode!r}")
    gains = gains if gains is not None else Gains()
    m = load_model(model_path)
    body = m.body(_BODY)
    mass, izz = float(body.mass[0]), float(body.inertia[2])
    drag_z = float(m.numeric("drag_z").data[0])
    drag_rot = float(m.numeric("drag_rot").data[0])
    motor = float(m.actuator(_MOTORS[0]).dynprm[0])
    # the actuator delay has no named view: index by the motor's id; effective = setting +
    # one physics step (MuJoCo notes)
    act_delay = float(m.actuator_delay[m.actuator(_MOTORS[0]).id]) + float(m.opt.timestep)
    g = -float(m.opt.gravity[2])
    th, pi, yw = STICK_CHANNELS["thrust"], STICK_CHANNELS["pitch"], STICK_CHANNELS["yaw_rate"]
    tz = mass / drag_z
    k_i = gains.k_rate_yaw * izz
    rate_lag = (izz + drag_rot * (motor + act_delay)) / (k_i + drag_rot)
    poles = sorted((th.tau_s, tz))
    pc = pitch_chain_of(m, mode=pitch_mode, gains=gains, channel=pi)
    how = f"pitch chain ({pitch_mode} mode), linearised: slow pair"
    pitch = {"K": (pc.K, f"pitch chain ({pitch_mode} mode): steady velocity per stick unit")}
    if pitch_mode == "rate":
        pitch["Tw"] = (pc.Tw, f"{how}, ~ sqrt(I k_rate / (g drag_xy h))")
        pitch["zeta"] = (pc.zeta, f"{how}, ~ (drag_xy / m) Tw / 2")
    pitch["Td"] = (pc.Td, f"link {pi.delay_s:g} s + fast poles' lags")
    pair = "slow pair" if pitch_mode == "rate" else "two slowest (real) poles"
    pitch["lag"] = (pc.lag, f"Td + 2 zeta Tw of the {pair}")
    return {
        "thrust": {
            "K": (g * tz, "g m / drag_z"),
            "Tp1": (poles[0], "smaller of stick filter and m / drag_z"),
            "Tp2": (poles[1], "larger of stick filter and m / drag_z"),
            "Td": (th.delay_s + motor + act_delay,
                   (f"link {th.delay_s:g} s + motor lag {motor:g} s + actuator delay "
                   f"{act_delay:g} s (open path; the lag folded into the delay)")),
            "lag": (th.delay_s + motor + act_delay + th.tau_s + tz, "sum of the above"),
        },
        "pitch": pitch,
        "yaw_rate": {
            "K": (k_i / (k_i + drag_rot), "closed rate loop k I / (k I + drag_rot)"),
            "Tp1": (yw.tau_s, "stick filter"),
            "Td": (yw.delay_s + rate_lag,
                   f"link {yw.delay_s:g} s + closed rate loop's lag {rate_lag:.4g} s"),
            "lag": (yw.delay_s + yw.tau_s + rate_lag, "sum of the above"),
        },
    }


def constants_matched_to_thesis(model_path: str | FsPath = MODEL_PATH) -> list[dict]:
    """The simulator's constants that were chosen to reproduce a value published in thesis
    003 Section 3.3 (not measured or derived from physics), each with its current value.

    One dict per constant: ``constant`` (where it lives), ``value``, ``unit``, ``role``,
    ``published`` (the thesis parameter it was chosen from), ``published_value`` (NaN for
    a structural choice) and ``source`` (the comment that says so). Values are read from
    :data:`STICK_CHANNELS`, :data:`PITCH_MODES` and the compiled model, so the list follows
    the code.
    """
    m = load_model(model_path)
    mass = float(m.body(_BODY).mass[0])
    drag_z = float(m.numeric("drag_z").data[0])
    th, pi, yw = (STICK_CHANNELS[a] for a in AXES)
    doc = "sim/quadcopter.py module docstring"
    return [
        {"constant": "STICK_CHANNELS['thrust'].tau_s", "value": th.tau_s, "unit": "s",
         "role": "throttle input filter: one thrust pole", "published": "thrust Tp1 (3.3.1)",
         "published_value": 0.40885, "source": f"{doc}: 'chosen to match'"},
        {"constant": "drag_z (models/quadcopter.xml) as m / drag_z", "value": mass / drag_z,
         "unit": "s", "role": f"vertical inflow damping {drag_z:g} N s/m (momentum theory "
         "gives ~2.4 N s/m, ~0.5 s): the other thrust pole", "published": "thrust Tp2 (3.3.1)",
         "published_value": 0.42283, "source": "models/quadcopter.xml: 'so that m / drag_z "
         "= 0.42 s, the slower thrust pole identified in thesis 003'"},
        {"constant": "STICK_CHANNELS['thrust'].delay_s", "value": th.delay_s, "unit": "s",
         "role": "link delay (+ 30 ms motor lag + 12 ms actuator delay = the thrust Td)",
         "published": "thrust Td (3.3.1)", "published_value": 0.6585,
         "source": f"{doc}: 'link delay 0.62 s (chosen)'"},
        {"constant": "STICK_CHANNELS['pitch'].delay_s", "value": pi.delay_s, "unit": "s",
         "role": "link delay of the pitch stick", "published": "pitch Td (3.3.2)",
         "published_value": 0.36505, "source": f"{doc}: 'chosen near the thesis's 0.365 s'"},
        {"constant": "impulse_response(pitch_mode=...) default", "value": PITCH_MODES[0],
         "unit": "-", "role": "the stick sets the pitch rate (self-levelling off)",
         "published": "the shape of the pitch model: underdamped, still accelerating 4 s "
         "after the impulse (3.3.2)", "published_value": math.nan,
         "source": f"{doc}: 'Rate mode is chosen because the thesis's fitted model keeps "
         "accelerating'"},
        {"constant": "STICK_CHANNELS['yaw_rate'].tau_s", "value": yw.tau_s, "unit": "s",
         "role": "yaw stick input filter: the yaw pole", "published": "yaw Tp1 (3.3.3)",
         "published_value": 1.8439, "source": f"{doc}: '1.80 s stick filter (chosen)'"},
        {"constant": "STICK_CHANNELS['yaw_rate'].delay_s", "value": yw.delay_s, "unit": "s",
         "role": "no link delay on yaw", "published": "yaw Td (3.3.3)",
         "published_value": 0.0044, "source": "STICK_CHANNELS comment: 'chosen so that "
         "identified constants are of the thesis's order'"},
    ]


def model_variant(*, drag_xy: float | None = None, rotor_height_m: float | None = None,
                  path: str | FsPath = MODEL_PATH) -> str:
    """MJCF text of the quadcopter model with other physical values (``None`` keeps one):
    ``drag_xy`` (N s/m, the custom numeric) and ``rotor_height_m`` (the rotor plane's and the
    rotor sites' height above the CG). For parameter studies; pass the text, written to a
    file, as ``model_path``."""
    spec = mujoco.MjSpec.from_file(str(path))
    if drag_xy is not None:
        spec.numeric("drag_xy").data = [check_real(drag_xy, "drag_xy", lo=0.0)]
    if rotor_height_m is not None:
        h = check_real(rotor_height_m, "rotor_height_m")
        for name in (_ROTOR_PLANE, *(f"rotor_{c}" for c in ("fl", "fr", "rr", "rl"))):
            site = spec.site(name)
            site.pos = [site.pos[0], site.pos[1], h]
    return spec.to_xml()
