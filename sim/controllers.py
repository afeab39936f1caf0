"""Waypoint following for the wheeled platform: pure pursuit with target areas and limits.

The dissertation's platform drives to target points with "target areas of a certain diameter
around the target points" and therefore takes curved turns (000_8f82f8df647bf685.txt,
Section 4.9). Here that is a pure-pursuit follower of the path's polyline:

- The platform follows segment i (waypoint i -> waypoint i+1). It switches to segment i+1 as
  soon as it is inside the target area of waypoint i+1 (distance < ``target_radius_m``);
  the turn therefore starts inside the target area and the platform cuts the corner on a
  curve instead of pivoting on the target point.
- Goal point: the foot of the perpendicular on the (extended) segment line, moved
  ``lookahead_m`` along the segment. Pure-pursuit curvature (Coulter 1992, CMU-RI-TR-92-01):
  ``kappa = 2 sin(alpha) / l`` with ``alpha`` the bearing of the goal point relative to the
  heading and ``l`` its distance.
- Speed: cruise speed, reduced so that ``v^2 |kappa| <= max_lateral_accel`` and
  ``v |kappa| <= max_turn_rate``, and on the final segment to ``sqrt(2 a d)`` so the platform
  stops at the route's end point (``d`` = distance left along the segment). With
  ``corner_speed_mps`` set (a car at speed, models/paths/car_block.toml) also to
  ``sqrt(v_c^2 + 2 a' d)`` before each corner, ``d`` = distance to the corner's target area:
  the platform brakes before the corner as a driver does, instead of entering it at cruise
  speed and turning wide under the lateral-acceleration limit. (``a' = 0.8 a`` as for the
  stop.) Off by default: the rover's paths do not set it.
- Commands (v, omega) are rate-limited (``max_accel_mps2``, ``max_yaw_accel_radps2``), so
  the wheel speeds ``(v -/+ omega b/2)/r`` are rate-limited too (no wheel skid at waypoint
  switches, ../shared/notes/mujoco.md).
- Turning flag (the "control information" of Section 3.4.2.1): ``|omega_cmd| >
  turning_curvature_per_m * cruise_speed_mps`` of the controller's own rate-limited command,
  i.e. the commanded turn rate exceeds that of a 15 m radius circle at cruise speed. The
  threshold scales with the cruise speed because pure pursuit's geometry does not: the same
  corner is driven on (nearly) the same curve at any speed, with turn rates proportional to
  the speed (measured at 0.2 m/s on square100: corner peak 0.082 rad/s, below the 0.1 rad/s
  that marked the corners at 1.5 m/s).

Everything here is pure Python on floats (the controller runs at 20-50 Hz inside the MuJoCo
loop; small numpy operations would cost more than the controller's arithmetic).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from sim.paths import Path

__all__ = [
    "PurePursuitParams",
    "PurePursuitState",
    "diff_drive_wheel_speeds",
    "pure_pursuit_curvature",
    "pure_pursuit_step",
    "rate_limit",
    "simulate_unicycle",
    "speed_limit",
]


@dataclass(frozen=True)
class PurePursuitParams:
    """Controller parameters (SI units). :meth:`from_path` takes the path's values.

    lookahead_m : distance of the goal point ahead of the foot point along the segment.
    target_radius_m : radius of the target area around each waypoint (Section 4.9).
    cruise_speed_mps, max_turn_rate_radps, max_lateral_accel_mps2, max_accel_mps2 :
        speed and limits. max_yaw_accel_radps2 : rate limit of the turn-rate command.
    corner_speed_mps : speed to brake to before each corner (None: no anticipation).
    turning_curvature_per_m : the turning flag is set while ``|omega_cmd| >
        turning_curvature_per_m * cruise_speed_mps`` (1/m). Default 1/15 (a 15 m turn
        radius; 0.1 rad/s at 1.5 m/s, 0.013 rad/s at 0.2 m/s): the corners peak at a
        curvature of about 0.4 1/m (measured at both speeds), while the heading corrections
        measured more than 8 m from a corner stay below 0.02 rad/s at 1.5 m/s and
        0.0009 rad/s at 0.2 m/s (curvature < 0.013 1/m), so the flag marks the corners and
        nothing else.
    stop_tolerance_m : the run ends once the platform is this close (along the final segment)
        to the end point, or past it, and has stopped.
    """

    lookahead_m: float = 1.5
    target_radius_m: float = 3.0
    cruise_speed_mps: float = 1.5
    max_turn_rate_radps: float = 0.8
    max_lateral_accel_mps2: float = 0.8
    max_accel_mps2: float = 0.5
    max_yaw_accel_radps2: float = 1.0
    turning_curvature_per_m: float = 1.0 / 15.0
    stop_tolerance_m: float = 0.02
    corner_speed_mps: float | None = None

    def __post_init__(self) -> None:
        for k, v in asdict(self).items():
            if v is None and k == "corner_speed_mps":
                continue
            if not (isinstance(v, (int, float)) and not isinstance(v, bool)
                    and math.isfinite(v) and v > 0):
                raise ValueError(f"{k}: must be a finite number > 0, got {v!r}")

    @classmethod
    def from_path(cls, path: Path, **overrides: float) -> PurePursuitParams:
        """Parameters from a path's fields (absent optional fields keep the defaults)."""
        kw: dict[str, float] = {"target_radius_m": path.target_radius_m,
                                "cruise_speed_mps": path.cruise_speed_mps}
        for k in ("lookahead_m", "max_turn_rate_radps", "max_lateral_accel_mps2",
                  "max_accel_mps2", "corner_speed_mps"):
            v = getattr(path, k)
            if v is not None:
                kw[k] = v
        unknown = sorted(set(overrides) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"controller parameter(s) {unknown}: unknown; "
                             f"known: {sorted(cls.__dataclass_fields__)}")
        kw.update(overrides)
        return cls(**kw)


@dataclass
class PurePursuitState:
    """Mutable controller state: current segment, last rate-limited commands, done flag."""

    segment: int = 0
    v_cmd: float = 0.0
    omega_cmd: float = 0.0
    finished: bool = False


def rate_limit(target: float, previous: float, max_rate: float, dt: float) -> float:
    """Move from ``previous`` toward ``target`` by at most ``max_rate * dt``."""
    step = max_rate * dt
    d = target - previous
    # min(max(d, -step), step), spelled out: builtins.max/min cost ~0.1 s of a 2000 s
    # simulation (two calls each at every control update); the same comparisons (max keeps
    # its first argument unless the second is larger, min unless the second is smaller)
    if -step > d:  # noqa: PLR1730 (builtins are slower here)
        d = -step
    if step < d:  # noqa: PLR1730 (builtins are slower here)
        d = step
    return previous + d


def pure_pursuit_curvature(x: float, y: float, yaw: float, gx: float, gy: float) -> float:
    """Pure-pursuit curvature toward goal (gx, gy): ``2 sin(alpha) / l`` (1/m, + = left).

    alpha = bearing of the goal in the vehicle frame, l = distance to the goal.
    """
    dx, dy = gx - x, gy - y
    dist = math.hypot(dx, dy)
    if dist < 1e-9:
        return 0.0
    # lateral offset of the goal in the vehicle frame over l^2: 2 sin(alpha)/l = 2 y_v / l^2
    lateral = -math.sin(yaw) * dx + math.cos(yaw) * dy
    return 2.0 * lateral / (dist * dist)


def speed_limit(kappa: float, p: PurePursuitParams) -> float:
    """Largest speed allowed on curvature ``kappa`` by the lateral-acceleration and turn-rate
    limits and the cruise speed (m/s)."""
    k = abs(kappa)
    v = p.cruise_speed_mps
    if k > 1e-12:
        v = min(v, math.sqrt(p.max_lateral_accel_mps2 / k), p.max_turn_rate_radps / k)
    return v


def diff_drive_wheel_speeds(v: float, omega: float, track_m: float, radius_m: float
                            ) -> tuple[float, float]:
    """Wheel angular velocities (left, right), rad/s, for body speed v (m/s) and yaw rate
    omega (rad/s) of a differential drive with wheel track ``track_m`` and radius ``radius_m``."""
    half = 0.5 * track_m * omega
    return (v - half) / radius_m, (v + half) / radius_m


def pure_pursuit_step(state: PurePursuitState, x: float, y: float, yaw: float,
                      vertices: list[tuple[float, float]], p: PurePursuitParams, dt: float
                      ) -> tuple[float, float, bool]:
    """One controller update. Mutates ``state``; returns (v_cmd, omega_cmd, turning).

    x, y, yaw : platform reference point (m) and heading (rad). vertices : polyline
    (start, targets...) as (x, y) tuples. dt : controller period (s).
    """
    last = len(vertices) - 2
    # waypoint switching: inside the target area of the segment's end point (Section 4.9)
    while state.segment < last:
        ex, ey = vertices[state.segment + 1]
        if math.hypot(ex - x, ey - y) < p.target_radius_m:
            state.segment += 1
        else:
            break
    ax, ay = vertices[state.segment]
    bx, by = vertices[state.segment + 1]
    sx, sy = bx - ax, by - ay
    seg_len = math.hypot(sx, sy)
    ux, uy = sx / seg_len, sy / seg_len
    along = (x - ax) * ux + (y - ay) * uy            # arclength of the foot point
    gx = ax + (along + p.lookahead_m) * ux            # goal on the extended segment line
    gy = ay + (along + p.lookahead_m) * uy
    kappa = pure_pursuit_curvature(x, y, yaw, gx, gy)
    v_target = speed_limit(kappa, p)
    if p.corner_speed_mps is not None and state.segment < last:
        # brake before the next corner: v <= sqrt(v_c^2 + 2 a' d), d = distance to its
        # target area (the turn starts there), a' = 0.8 a as for the final stop
        d = max(seg_len - along - p.target_radius_m, 0.0)
        v_target = min(v_target, math.sqrt(p.corner_speed_mps ** 2
                                            + 2.0 * 0.8 * p.max_accel_mps2 * d))
    if state.segment == last:
        remaining = seg_len - along
        if remaining <= p.stop_tolerance_m:
            state.finished = True
        # stopping profile v <= sqrt(2 a' d), zero at the end point; a' = 0.8 a leaves the
        # rate-limited command margin to follow it without overshooting the end point
        v_target = 0.0 if state.finished else min(
            v_target, math.sqrt(2.0 * 0.8 * p.max_accel_mps2 * remaining))
    state.v_cmd = rate_limit(v_target, state.v_cmd, p.max_accel_mps2, dt)
    # the turn rate obeys both limits at the speed actually commanded (v omega <= a_lat):
    # w_max = min(max_turn_rate, a_lat / max(v, 1e-9)), omega_target = max(-w_max,
    # min(w_max, v kappa)), the comparisons of min/max spelled out (as in rate_limit)
    v_pos = state.v_cmd
    if v_pos < 1e-9:  # noqa: PLR1730 (builtins are slower here)
        v_pos = 1e-9
    w_max = p.max_turn_rate_radps
    w_lat = p.max_lateral_accel_mps2 / v_pos
    if w_lat < w_max:  # noqa: PLR1730 (builtins are slower here)
        w_max = w_lat
    inner = w_max
    w_curve = state.v_cmd * kappa
    if w_curve < inner:  # noqa: PLR1730 (builtins are slower here)
        inner = w_curve
    omega_target = -w_max
    if inner > omega_target:  # noqa: PLR1730 (builtins are slower here)
        omega_target = inner
    state.omega_cmd = rate_limit(omega_target, state.omega_cmd, p.max_yaw_accel_radps2, dt)
    turning = abs(state.omega_cmd) > p.turning_curvature_per_m * p.cruise_speed_mps
    return state.v_cmd, state.omega_cmd, turning


def simulate_unicycle(path: Path, params: PurePursuitParams | None = None, *, dt: float = 0.02,
                      max_steps: int = 10_000_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same controller driving an ideal kinematic unicycle (no dynamics, no slip).

    A reference for the MuJoCo platform: each command (v, omega) is held for ``dt`` and
    integrated exactly (a circular arc). Starts at rest on ``path.start`` facing the first
    segment, ends when the controller has finished and stopped.

    Returns t (n,) s, xy (n, 2) m, yaw (n,) rad (unwrapped).
    """
    p = params if params is not None else PurePursuitParams.from_path(path)
    verts = [(float(a), float(b)) for a, b in path.polyline[:, :2]]
    x, y = verts[0]
    yaw = math.atan2(verts[1][1] - y, verts[1][0] - x)
    state = PurePursuitState()
    out = [(0.0, x, y, yaw)]
    for k in range(1, max_steps + 1):
        v, w, _ = pure_pursuit_step(state, x, y, yaw, verts, p, dt)
        if state.finished and v == 0.0:
            break
        if abs(w) > 1e-12:       # exact arc of radius v / w
            x += v / w * (math.sin(yaw + w * dt) - math.sin(yaw))
            y -= v / w * (math.cos(yaw + w * dt) - math.cos(yaw))
        else:
            x += v * dt * math.cos(yaw)
            y += v * dt * math.sin(yaw)
        yaw += w * dt
        out.append((k * dt, x, y, yaw))
    else:
        raise RuntimeError(f"unicycle did not finish path {path.name!r} in {max_steps} steps")
    a = np.array(out)
    return a[:, 0], a[:, 1:3], a[:, 3]
