"""The wheeled GPS platform in MuJoCo: drive a path, log exact antenna positions (Truth).

Replaces the dissertation's Simulink vehicle (000_8f82f8df647bf685.txt, Section 4.1.2), which
provided the "perfect" trajectory of the eight antennas while the platform drove Path 1 and
Path 2 (Section 4.9).

Model: ``models/rover.xml``, a 64 kg differential-drive platform (1.5 x 1.0 m roof, wheels
r = 0.2 m on velocity servos, track 1.1 m, frictionless casters), ``implicitfast`` steps of
20 ms up to 0.3 m/s (Paths 1 and 2), else the XML's 10 ms (:func:`default_timestep_s`;
``timestep_s`` overrides it; see the XML for the measured choice).
The wheels collide as spheres (one contact point each; see the XML for the measured reason),
so the platform turns at the rate its wheel speeds imply and follows the same controller on
an ideal unicycle (:func:`sim.controllers.simulate_unicycle`) to about 2 cm at the corners.
The antennas are MuJoCo sites ``gps_<name>`` generated at load time from the
:class:`~estimator.configuration.SensorConfig` with ``mujoco.MjSpec`` (:func:`build_rover_model`),
so the layout has one source of truth: site = (x, y, mount_height_m) in the chassis frame for a
2-D configuration, (x, y, mount_height_m + z) for a 3-D one. A model that already contains
``gps_`` sites is refused.

Other vehicles: a path may name its MuJoCo model (``vehicle = "car"`` in the path file:
``models/car.xml``, a car-sized platform driven by its rear axle, see that file for why it is
built this way); any such model has the rover's named parts (body "chassis" with free joint
"root", wheel bodies, geoms and velocity actuators "wheel_left"/"wheel_right"). The
controller steers the midpoint of the driven wheels (the axle's no-slip point; on the rover
it is the chassis origin, so the rover's numbers are unchanged by this generality), and
``meta["no_slip_point_m"]`` records that point in the chassis frame (x forward, y left, m),
for estimators that model the non-holonomic constraint (estimator.pose_filter).

Reference point ("CG" in the Truth): the chassis body origin, on the ground plane directly
below the roof centre. For ``rover_gps8`` that is the mean of antennas 2, 3, 6, 7 (Eq. 3.8)
projected to the ground (z ~ 0; the contacts sink the wheels by 0.056 mm at 20 ms steps,
0.014 mm at 10 ms). The chassis tilts by < 1e-4 rad on the soft contacts while it accelerates
(measured on square20: 3e-5 rad at 0.2 m/s, 5e-6 at 1.5 m/s), so the roof centre, 0.6 m up,
is up to 0.02 mm horizontally from the body origin. The drive axle
passes under it, so it has no lateral slip and is the point the controller steers.

Control: :mod:`sim.controllers` pure pursuit at ``control_rate_hz`` (default from the cruise speed,
:func:`default_control_steps`: 25 Hz at 0.2 m/s (20 ms steps), 50 Hz at 1.5 m/s); between
updates ``mj_step(model, data, nstep)`` advances the physics. Sample times come from an
integer step counter (``t = step * timestep``; sample k at step ``round(k / (rate *
timestep))``), and positions are logged after ``mj_kinematics`` (site positions read after
``mj_step`` are one step old). The turning flag of sample k is True if any command issued in
``[t_{k-1}, t_k)`` had ``|omega_cmd| > turning_curvature_per_m * cruise_speed_mps`` (the
controller's own "control information", Section 3.4.2.1).

Speed (issue 27; CPU time, best of 3, on this shared 2-core machine at load average 6-11,
default settings; ``python -m experiments.bench --only sim``): Path 1 (square100 at
0.2 m/s, 1984 s simulated) 1.06-1.28 s, Path 2 (square200, 3985 s) 1.88-2.25 s (before
issue 27, 5 ms steps: 3.65 and 7.65 s at load 7-8; Path 1 3.4 s at load 1.2). A step costs
6-8 us whatever its length (the Newton solver converges in one iteration; no solver option
changed that measurably), so the time scales with the number of steps: hence the 20 ms step
on slow routes. ``mj_step`` takes about 65 % of the CPU time of Path 1 (timed around each
call: 0.77-0.79 of 1.20-1.23 s at load 9), the Python controller at 25 Hz and the 1 Hz
logging the rest.

Randomness: none. The run is deterministic (same inputs -> bit-identical arrays, tested); the
``seed`` is recorded and enters the cache key only, so seeded sweeps stay uniform.

The run starts at rest on the path's start point facing the first segment (after a 1 s
unlogged settle of the contacts: at 20 ms steps they need about 0.9 s to come within 1 um
of their rest depth) and ends at the first sample after the platform has reached
the route's end point and stopped (speed < 1 mm/s).
"""

from __future__ import annotations

import math
import time
from pathlib import Path as FsPath
from typing import Any

import mujoco
import numpy as np

from estimator._checks import check_real
from estimator.configuration import MODELS_DIR, SensorConfig
from sim.cache import cached, key_hash, truth_key
from sim.controllers import (
    PurePursuitParams,
    PurePursuitState,
    diff_drive_wheel_speeds,
    pure_pursuit_step,
)
from sim.paths import Path, load_path, path_errors
from sim.truth import Truth

__all__ = ["COARSE_TIMESTEP_S", "MAX_SERVO_STEP_RATIO", "MAX_TIMESTEP_S", "ROVER_XML",
           "SITE_PREFIX", "build_rover_model", "default_control_steps", "default_timestep_s",
           "servo_step_ratio", "simulate_rover"]

ROVER_XML = MODELS_DIR / "rover.xml"
SITE_PREFIX = "gps_"
#: Largest physics step accepted (contacts' solref time constants are raised to two steps,
#: see :func:`build_rover_model`).
MAX_TIMESTEP_S = 0.02
#: Default physics step of slow routes (:func:`default_timestep_s`), s ...
COARSE_TIMESTEP_S = 0.02
#: ... used while the platform travels at most this far per step at cruise speed, m, ...
_COARSE_TRAVEL_M = 0.006
#: ... and the wheel servos are resolved (:func:`servo_step_ratio`; measured command-step
#: undershoot 0.6, 1.5, 2.8 and 5.4 mm/s at ratios 1.2, 1.4, 1.7 and 2.2).
MAX_SERVO_STEP_RATIO = 1.5
_SETTLE_S = 1.0
#: Default control period: the platform moves at most this far between controller updates
#: at cruise speed (3 cm = 50 Hz at 1.5 m/s), ...
_CTRL_TRAVEL_M = 0.03
#: ... but the controller never runs slower than this (see default_control_steps).
_MIN_CTRL_RATE_HZ = 20.0


def default_control_steps(cruise_speed_mps: float, timestep_s: float) -> int:
    """Physics steps per controller update when ``control_rate_hz`` is not given.

    The largest whole number of steps in which the platform travels at most
    ``_CTRL_TRAVEL_M`` = 3 cm at cruise speed, capped so that the controller runs at
    least ``_MIN_CTRL_RATE_HZ`` = 20 Hz, and at least one step. At the default steps
    (:func:`default_timestep_s`): 50 Hz at 1.5 m/s (10 ms), 25 Hz at 0.2 m/s (20 ms; 20 Hz
    is not a whole number of steps). Measured on square100 at 0.2 m/s, 5 ms: 10 Hz gave
    4.0 mm straight-line error (at the final stop) and 20 Hz 0.8 mm for the same wall time
    (the controller was < 10 % of it), hence the 20 Hz floor.
    """
    cruise_speed_mps = check_real(cruise_speed_mps, "cruise_speed_mps", lo=0.0, lo_open=True)
    timestep_s = check_real(timestep_s, "timestep_s", lo=0.0, lo_open=True)
    by_travel = math.floor(_CTRL_TRAVEL_M / (cruise_speed_mps * timestep_s) + 1e-9)
    by_rate = math.floor(1.0 / (_MIN_CTRL_RATE_HZ * timestep_s) + 1e-9)
    return max(1, min(by_travel, by_rate))


def default_timestep_s(cruise_speed_mps: float, model: mujoco.MjModel | None = None
                       ) -> float | None:
    """Physics step when ``simulate_rover`` is not given one: :data:`COARSE_TIMESTEP_S`
    (20 ms) while the platform travels at most 6 mm per step at cruise speed (up to
    0.3 m/s: Paths 1 and 2 drive at 0.2 m/s) and, if ``model`` is given, its wheel servos
    are resolved at that step (:func:`servo_step_ratio` <= :data:`MAX_SERVO_STEP_RATIO`);
    else None (the XML's step: 10 ms for the rover, 5 ms for the car, whose servos are
    not resolved at 20 ms). See models/rover.xml for the measurements behind both.
    """
    cruise_speed_mps = check_real(cruise_speed_mps, "cruise_speed_mps", lo=0.0, lo_open=True)
    if cruise_speed_mps * COARSE_TIMESTEP_S > _COARSE_TRAVEL_M + 1e-12:
        return None
    if model is not None and servo_step_ratio(model, COARSE_TIMESTEP_S) > MAX_SERVO_STEP_RATIO:
        return None
    return COARSE_TIMESTEP_S


def servo_step_ratio(model: mujoco.MjModel, timestep_s: float) -> float:
    """Largest ``kv h / M_jj`` of the wheel velocity servos "wheel_left"/"wheel_right":
    servo gain (N m s/rad) times the step over the wheel joint's inertia including its
    armature (kg m^2, the mass-matrix diagonal). Above ~1.5 a speed-command step makes the
    chassis swing against the wheels (models/rover.xml)."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    ratios = []
    for name in ("wheel_left", "wheel_right"):
        act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        if act < 0:
            raise ValueError(f"xml_path: model has no actuator {name!r}")
        dof = model.jnt_dofadr[model.actuator_trnid[act, 0]]
        ratios.append(float(model.actuator_gainprm[act, 0]) * timestep_s
                      / float(full[dof, dof]))
    return max(ratios)


def _soften_to_two_steps(spec: mujoco.MjSpec, timestep_s: float) -> None:
    """Raise every contact solref time constant below two steps to ``2 * timestep_s``.

    MuJoCo does the same silently (its ``refsafe``); doing it here puts the value used in the
    compiled XML (and so in the cache key). Direct (negative) solref values are left alone.
    """
    for item in (*spec.pairs, *spec.geoms):
        if item.solref[0] > 0 and item.solref[0] < 2.0 * timestep_s:
            item.solref = [2.0 * timestep_s, item.solref[1]]


def build_rover_model(config: SensorConfig, xml_path: str | FsPath = ROVER_XML, *,
                      timestep_s: float | None = None) -> tuple[mujoco.MjModel, str]:
    """Compile the rover with one site per sensor of ``config`` (generated with MjSpec).

    ``timestep_s`` overrides the physics step of the XML (``<option timestep>``, 10 ms in
    models/rover.xml, 5 ms in models/car.xml); it must be > 0 and at most
    :data:`MAX_TIMESTEP_S`. Contacts whose ``solref`` time constant is shorter than two steps
    get two steps (:func:`_soften_to_two_steps`; MuJoCo would soften them silently).

    Returns (model, xml) where ``xml`` is the full MJCF text of what was compiled (it enters
    the cache key, so the timestep does too). Raises ValueError if the model has no body
    "chassis", already contains sites named ``gps_*``, the timestep is out of range, or the
    compiled sites do not reproduce the configuration.
    """
    spec = mujoco.MjSpec.from_file(str(xml_path))
    if timestep_s is not None:
        if isinstance(timestep_s, bool) or not isinstance(timestep_s, (int, float)) or not (
                math.isfinite(timestep_s) and 0 < timestep_s <= MAX_TIMESTEP_S):
            raise ValueError(f"timestep_s: must be a number in (0, {MAX_TIMESTEP_S}] s, "
                             f"got {timestep_s!r}")
        spec.option.timestep = float(timestep_s)
        _soften_to_two_steps(spec, float(timestep_s))
    chassis = spec.body("chassis")
    if chassis is None:
        raise ValueError(f"xml_path: {xml_path} has no body named 'chassis'")
    existing = [s.name for s in spec.sites if s.name.startswith(SITE_PREFIX)]
    if existing:
        raise ValueError(f"xml_path: {xml_path} already defines antenna sites {existing}; "
                         "sites are generated from the SensorConfig, remove them from the XML")
    bp = config.body_positions
    local = np.zeros((config.m, 3))
    local[:, :2] = bp[:, :2]
    local[:, 2] = config.mount_height_m + (bp[:, 2] if config.d == 3 else 0.0)
    for name, pos in zip(config.names, local):
        chassis.add_site(name=f"{SITE_PREFIX}{name}", pos=pos.tolist(), size=[0.04, 0, 0],
                         rgba=[0.9, 0.2, 0.1, 1])
    model = spec.compile()
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, f"{SITE_PREFIX}{n}")
           for n in config.names]
    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    if min(ids) < 0 or np.any(model.site_bodyid[ids] != body) or not np.allclose(
            model.site_pos[ids], local, rtol=0, atol=1e-12):
        raise ValueError(f"config: compiled antenna sites do not match {config.name!r}")
    return model, spec.to_xml()


def _yaw_of_quat(w: float, x: float, y: float, z: float) -> float:
    """Heading (rad, CCW from +x) of a (w, x, y, z) quaternion, in (-pi, pi]."""
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return math.pi if yaw == -math.pi else yaw


def simulate_rover(
    path: Path | str,
    config: SensorConfig | str = "rover_gps8",
    *,
    seed: int = 0,
    sample_rate_hz: float | None = None,
    cache_dir: str | FsPath | None | bool = None,
    control_rate_hz: float | None = None,
    timestep_s: float | None = None,
    controller: dict[str, float] | None = None,
    xml_path: str | FsPath | None = None,
    max_duration_s: float | None = None,
) -> Truth:
    """Drive ``path`` with the rover carrying ``config``'s antennas; return the exact Truth.

    Parameters
    ----------
    path : a :class:`~sim.paths.Path` or a name in models/paths/ (e.g. "square100", Path 1).
    config : a SensorConfig or a name in models/configs/ (default "rover_gps8").
    seed : recorded and part of the cache key; the simulation itself is deterministic.
    sample_rate_hz : Truth sample rate; default ``path.sample_rate_hz`` (GPS: 1 Hz).
    cache_dir : None = results/cache/truth, a directory, or False to disable caching.
    control_rate_hz : controller rate; the control period must be a whole number of physics
        steps. Default: from the cruise speed (:func:`default_control_steps`: at most 3 cm of
        travel per update, at least 20 Hz; 25 Hz at 0.2 m/s, 50 Hz at 1.5 m/s).
    timestep_s : physics step, default :func:`default_timestep_s` (20 ms up to 0.3 m/s,
        else the XML's: 10 ms for the rover, 5 ms for the car); at most
        :data:`MAX_TIMESTEP_S` = 20 ms. Both rates enter the cache key (through the
        compiled XML and the run parameters).
    controller : overrides of :class:`~sim.controllers.PurePursuitParams` fields
        (e.g. ``{"turning_curvature_per_m": 0.1}``); the rest comes from the path.
    xml_path : the MJCF model (default: ``models/<path.vehicle>.xml`` if the path names a
        vehicle, else models/rover.xml); it must have a body "chassis", hinge joints and
        velocity actuators named "wheel_left"/"wheel_right".
    max_duration_s : give up (RuntimeError) if the route is not finished by then; default
        ``2 * length / cruise + 120`` s.

    Returns
    -------
    Truth with t (n,) s, sensor_positions (n, m, 3) m (dead sensors included: the antenna
    exists even if its receiver never reports), cg (n, 3) body origin, yaw (n,) rad,
    speed (n,) m/s, yaw_rate (n,) rad/s, turning (n,) bool, and meta (model, path, params,
    seed, versions, hash, wall time, and ``path_errors``: :func:`sim.paths.path_errors` of
    the reference point at the control rate, since 1 Hz samples 1.5 m apart miss the corners).
    """
    path = load_path(path)
    if isinstance(config, str):
        config = SensorConfig.load(config)
    if not isinstance(config, SensorConfig):
        raise ValueError(  # noqa: TRY004 - DESIGN.md: bad input raises ValueError
            f"config: expected a SensorConfig or a name, got {type(config).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"seed: must be an int, got {seed!r}")  # noqa: TRY004
    rate = path.sample_rate_hz if sample_rate_hz is None else sample_rate_hz
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (
            math.isfinite(rate) and rate > 0):
        raise ValueError(f"sample_rate_hz: must be a finite number > 0, got {rate!r}")
    params = PurePursuitParams.from_path(path, **(controller or {}))
    if xml_path is None:
        xml_path = ROVER_XML if path.vehicle is None else MODELS_DIR / f"{path.vehicle}.xml"
        if not FsPath(xml_path).is_file():
            raise ValueError(f"path: vehicle {path.vehicle!r} has no model {xml_path}")
    if timestep_s is None:
        timestep_s = default_timestep_s(params.cruise_speed_mps,
                                        build_rover_model(config, xml_path)[0])
    model, xml = build_rover_model(config, xml_path, timestep_s=timestep_s)
    dt = float(model.opt.timestep)
    if control_rate_hz is None:
        steps_per_ctrl = float(default_control_steps(params.cruise_speed_mps, dt))
        control_rate_hz = 1.0 / (steps_per_ctrl * dt)
    else:
        if isinstance(control_rate_hz, bool) or not isinstance(control_rate_hz, (int, float)) \
                or not (math.isfinite(control_rate_hz) and control_rate_hz > 0):
            raise ValueError(f"control_rate_hz: must be a finite number > 0, "
                             f"got {control_rate_hz!r}")
        steps_per_ctrl = 1.0 / (control_rate_hz * dt)
        if not (abs(steps_per_ctrl - round(steps_per_ctrl)) < 1e-9
                and round(steps_per_ctrl) >= 1):
            raise ValueError(f"control_rate_hz: the control period must be a whole number of "
                             f"{dt} s steps, got {control_rate_hz!r}")
    if max_duration_s is None:
        max_duration_s = 2.0 * path.length_m / params.cruise_speed_mps + 120.0
    run_params: dict[str, Any] = {
        "controller": params.__dict__.copy(), "control_rate_hz": float(control_rate_hz),
        "sample_rate_hz": float(rate), "timestep_s": dt, "settle_s": _SETTLE_S,
        "max_duration_s": float(max_duration_s),
    }
    key = truth_key(simulator="rover", model_xml=xml, path=path, params=run_params, seed=seed,
                    config=config)

    def compute() -> Truth:
        return _run(model, config, path, params, round(steps_per_ctrl), float(rate),
                    float(max_duration_s), meta={
                        "simulator": "sim.rover.simulate_rover",
                        "model": str(xml_path), "config": config.name, "path": path.to_dict(),
                        "params": run_params, "seed": int(seed), "deterministic": True,
                        "versions": key["versions"], "code_salt": key["code_salt"],
                        "hash": key_hash(key)})

    if cache_dir is False:
        return compute()
    return cached(key, compute, None if cache_dir in (None, True) else cache_dir)


def _run(model: mujoco.MjModel, config: SensorConfig, path: Path, params: PurePursuitParams,
         steps_per_ctrl: int, rate: float, max_duration_s: float, meta: dict) -> Truth:
    """The simulation loop (see the module docstring for the timing conventions)."""
    wall0 = time.perf_counter()
    data = mujoco.MjData(model)
    dt = float(model.opt.timestep)
    name2id = mujoco.mj_name2id
    obj = mujoco.mjtObj
    site_ids = np.array([name2id(model, obj.mjOBJ_SITE, f"{SITE_PREFIX}{n}") for n in config.names])
    body = name2id(model, obj.mjOBJ_BODY, "chassis")
    root = model.jnt_qposadr[name2id(model, obj.mjOBJ_JOINT, "root")]
    root_v = model.jnt_dofadr[name2id(model, obj.mjOBJ_JOINT, "root")]
    act_l = name2id(model, obj.mjOBJ_ACTUATOR, "wheel_left")
    act_r = name2id(model, obj.mjOBJ_ACTUATOR, "wheel_right")
    wheel_l = name2id(model, obj.mjOBJ_BODY, "wheel_left")
    wheel_r = name2id(model, obj.mjOBJ_BODY, "wheel_right")
    if min(act_l, act_r, wheel_l, wheel_r, root) < 0:
        raise ValueError("xml_path: model needs joint 'root', bodies and actuators "
                         "'wheel_left'/'wheel_right'")
    # vehicle geometry read from the model by name: track = distance between the wheel
    # bodies, radius = the wheel geom's size
    track = float(np.linalg.norm(model.body_pos[wheel_l] - model.body_pos[wheel_r]))
    radius = float(model.geom_size[name2id(model, obj.mjOBJ_GEOM, "wheel_left"), 0])
    # the controlled point: the driven axle's midpoint in the chassis frame (the rover's
    # is the chassis origin: (0, 0), and adding 0.0 below changes no bit of its numbers)
    axle_x, axle_y = (float(v) for v in
                      0.5 * (model.body_pos[wheel_l, :2] + model.body_pos[wheel_r, :2]))

    # initial pose: the controlled point on the start point, facing the first segment
    verts = [(float(a), float(b)) for a, b in path.polyline[:, :2]]
    yaw0 = math.atan2(verts[1][1] - verts[0][1], verts[1][0] - verts[0][0])
    c0, s0 = math.cos(yaw0), math.sin(yaw0)
    data.qpos[root:root + 3] = [verts[0][0] - (c0 * axle_x - s0 * axle_y),
                                verts[0][1] - (s0 * axle_x + c0 * axle_y), 0.0]
    data.qpos[root + 3:root + 7] = [math.cos(yaw0 / 2), 0.0, 0.0, math.sin(yaw0 / 2)]
    mujoco.mj_forward(model, data)
    mujoco.mj_step(model, data, round(_SETTLE_S / dt))   # let the contacts settle

    steps_per_sample = 1.0 / (rate * dt)
    n_max = int(max_duration_s * rate) + 2
    m = config.m
    t_log = np.empty(n_max)
    sp_log = np.empty((n_max, m, 3))
    cg_log = np.empty((n_max, 3))
    yaw_log = np.empty(n_max)
    speed_log = np.empty(n_max)
    yr_log = np.empty(n_max)
    turn_log = np.zeros(n_max, dtype=bool)

    state = PurePursuitState()
    ctrl_dt = steps_per_ctrl * dt
    qpos, qvel, ctrl = data.qpos, data.qvel, data.ctrl
    step = 0          # integer step counter since the end of the settle (t = step * dt)
    k = 0             # next sample index
    next_sample = 0
    next_ctrl = 0
    turning_acc = False
    # the reference point at every control update, as two lists of floats (one array each
    # at the end: ~10x faster than an array from a list of pairs)
    trace_x: list[float] = []
    trace_y: list[float] = []
    max_steps = math.ceil(max_duration_s / dt)
    step_limit = max_steps + steps_per_sample
    mj_step = mujoco.mj_step
    while True:
        if step == next_sample:
            mujoco.mj_kinematics(model, data)      # positions of the current qpos
            R = data.xmat[body]
            w_world = R.reshape(3, 3) @ qvel[root_v + 3:root_v + 6]   # free joint: body-frame
            t_log[k] = step * dt
            sp_log[k] = data.site_xpos[site_ids]
            cg_log[k] = data.xpos[body]
            yaw_log[k] = _yaw_of_quat(*qpos[root + 3:root + 7])
            speed_log[k] = math.hypot(qvel[root_v], qvel[root_v + 1])
            yr_log[k] = w_world[2]
            turn_log[k] = turning_acc
            turning_acc = False
            k += 1
            if state.finished and speed_log[k - 1] < 1e-3:
                break
            if k >= n_max:
                raise RuntimeError(f"rover did not finish path {path.name!r} within "
                                   f"max_duration_s = {max_duration_s} s")
            next_sample = round(k * steps_per_sample)
        if step == next_ctrl:
            q = qpos[root:root + 7].tolist()       # one conversion to Python floats
            yaw = _yaw_of_quat(q[3], q[4], q[5], q[6])
            cy, sy = math.cos(yaw), math.sin(yaw)
            x = q[0] + (cy * axle_x - sy * axle_y)
            y = q[1] + (sy * axle_x + cy * axle_y)
            trace_x.append(x)
            trace_y.append(y)
            v, omega, turning = pure_pursuit_step(state, x, y, yaw, verts, params, ctrl_dt)
            ctrl[act_l], ctrl[act_r] = diff_drive_wheel_speeds(v, omega, track, radius)
            turning_acc = turning_acc or turning
            next_ctrl += steps_per_ctrl
        nxt = next_sample if next_sample < next_ctrl else next_ctrl  # noqa: FURB136 (faster)
        if nxt > step_limit:
            raise RuntimeError(f"rover did not finish path {path.name!r} within "
                               f"max_duration_s = {max_duration_s} s")
        mj_step(model, data, nxt - step)
        step = nxt
    wall = time.perf_counter() - wall0
    n = k
    cg = cg_log[:n].copy()
    ye = float(yaw_log[n - 1])
    trace_x.append(float(cg[-1, 0]) + (math.cos(ye) * axle_x - math.sin(ye) * axle_y))
    trace_y.append(float(cg[-1, 1]) + (math.sin(ye) * axle_x + math.cos(ye) * axle_y))
    # path errors at the control rate: 1 Hz is too coarse
    errors = path_errors(np.column_stack((np.array(trace_x), np.array(trace_y))), path)
    meta = {**meta, "no_slip_point_m": [axle_x, axle_y],
            "sim_seconds": float(t_log[n - 1]), "wall_seconds": wall,
            "sim_seconds_per_wall_second": float(t_log[n - 1]) / wall,
            "path_errors": errors.as_dict()}
    return Truth(t=t_log[:n].copy(), sensor_positions=sp_log[:n].copy(),
                 sensor_names=config.names, cg=cg, yaw=yaw_log[:n].copy(),
                 speed=speed_log[:n].copy(), yaw_rate=yr_log[:n].copy(),
                 turning=turn_log[:n].copy(), meta=meta)
