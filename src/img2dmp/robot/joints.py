"""The joint trajectory of a writing run: export for a real arm, limits, replay.

A :class:`JointTrajectory` is what a position-controlled KUKA LBR iiwa needs to write the
digit again: time stamps at the control rate (from 0, the start posture at rest), seven
joint positions and velocities, the joint names. Its positions are either (``joints``,
:data:`JOINT_SOURCES`) the controller's **reference** (the default): its IK solution
``q_d`` of the commanded point on the paper at every control step, moved along the pen to
the depth the simulated pen pressed to (:func:`reference_at_tip_depth`; the offset
smoothed, :func:`depth_offset_m`), or the
simulated arm's **measured** joints after each step (a torque-controlled arm that lags
its reference and yields to the pen's force). :func:`save_joint_trajectory` writes it as CSV and
JSON after checking it against the iiwa's limits (``IIWA_POSITION_LIMITS_RAD`` from the
robot model, ``IIWA_VELOCITY_LIMITS_RAD_S`` from KUKA's data sheet of the LBR iiwa 14
R820, whose masses the model has; the model's own 10 rad/s is a placeholder); its
accelerations are measured against ``IIWA_ACCELERATION_LIMITS_RAD_S2`` (a planning
limit: :meth:`JointTrajectory.acceleration_violation` is for a warning).
:func:`replay_joint_trajectory` plays it back in a fresh simulation by joint position
control, as a real controller would, and returns where the pen touched the paper.

JSON (``"format": "img2dmp-joint-trajectory"``, version 1)::

    {"format", "version", "robot", "joint_names": [7], "control_rate_hz",
     "units": {"time": "s", "position": "rad", "velocity": "rad/s"},
     "limits": {"position_rad": [[lo, hi]] * 7, "velocity_rad_s": [7],
                "acceleration_rad_s2": [7]},
     "acceleration_peak": {"joint", "acceleration_rad_s2", "time_s", "limit_rad_s2",
                           "share"}  -- from the velocities (a note: not read back),
     "scene": SceneConfig fields (where the paper is),
     "joints": "reference" or "measured" (optional: a file without it holds "measured"),
     "time_s": [N], "position_rad": [N][7], "velocity_rad_s": [N][7]}

CSV: a header ``time_s, <joint>_rad x 7, <joint>_rad_s x 7`` and one row per sample.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
from dataclasses import dataclass

import numpy as np

from .._files import atomic_write_text
from .scene import SceneConfig, WritingScene
from .strokes import ink_points, stroke_spans

FORMAT = "img2dmp-joint-trajectory"
VERSION = 1
IIWA_JOINT_NAMES = tuple(f"lbr_iiwa_joint_{j}" for j in range(1, 8))
# Axis ranges of the LBR iiwa (170, 120, 170, 120, 170, 120, 175 degrees), as in the model.
IIWA_POSITION_LIMITS_RAD = np.radians([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])
# Axis speeds of the LBR iiwa 14 R820 (85, 85, 100, 75, 130, 135, 135 degrees per second).
IIWA_VELOCITY_LIMITS_RAD_S = np.radians([85.0, 85.0, 100.0, 75.0, 130.0, 135.0, 135.0])
# Joint accelerations: KUKA publishes none for the LBR iiwa 14 R820 (its data sheet gives
# ranges, speeds and torques only). 10 rad/s^2 at every joint is what the lbr-stack's
# MoveIt configuration of the iiwa 14 plans with (github.com/lbr-stack/lbr_fri_ros2_stack,
# lbr_moveit_config/iiwa14_moveit_config/config/joint_limits.yaml, max_acceleration: 10.0,
# before its default scaling of 0.1): a planning limit in wide use, not a KUKA value.
IIWA_ACCELERATION_LIMITS_RAD_S2 = np.full(7, 10.0)
ROBOT = "KUKA LBR iiwa 14 R820 (pybullet_data kuka_iiwa/model.urdf) with a pen on the flange"
SUFFIXES = (".csv", ".json")
#: What a trajectory's positions are (``JointTrajectory.joints``, ``--joints``): the
#: controller's reference at the pen's measured depth (the default), or the simulated
#: arm's measured joints.
JOINT_SOURCES = ("reference", "measured")
DEFAULT_JOINTS = "reference"
#: The depth offset of ``reference`` (:func:`depth_offset_m`): its zero-phase low-pass
#: cut-off (while the pen touched, >= 99.5 % of the offset's variance lies below it at
#: 240 Hz and 1 kHz on the samples), the span over which it comes in before a touch-down
#: and goes out after a lift-off, and the longest loss of contact inside one touch.
DEPTH_CUTOFF_HZ = 10.0
DEPTH_RAMP_S = 0.1
DEPTH_CONTACT_GAP_S = 0.02


@dataclass(frozen=True)
class JointTrajectory:
    """Joint positions and velocities of the iiwa over time (N samples).

    Attributes
    ----------
    time_s : ndarray [N]
        Increasing time stamps, one control period apart, from 0.
    position_rad, velocity_rad_s : ndarray [N, 7]
        Joint positions and velocities.
    joint_names : tuple of 7 str
    control_rate_hz : float
    scene : dict
        The :class:`SceneConfig` fields of the cell it was written in.
    joints : str
        What the positions are, one of :data:`JOINT_SOURCES`.
    """

    time_s: np.ndarray
    position_rad: np.ndarray
    velocity_rad_s: np.ndarray
    joint_names: tuple = IIWA_JOINT_NAMES
    control_rate_hz: float = 240.0
    scene: dict = dataclasses.field(default_factory=dict)
    joints: str = "measured"

    @classmethod
    def from_result(cls, result, joints: str = DEFAULT_JOINTS) -> JointTrajectory:
        """The trajectory of a ``WritingResult``: its start posture at ``t = 0`` (at rest),
        then one sample per control step of its log.

        ``joints="reference"``: the controller's reference ``q_d`` of each step at the
        depth the pen reached while it touched the paper, smoothed
        (:func:`reference_at_tip_depth`, :func:`depth_offset_m`), its velocities the
        positions' finite differences (the first from rest); ``"measured"``: the
        simulated arm's joint positions and velocities after each step."""
        if joints not in JOINT_SOURCES:
            raise ValueError(f"joints must be one of {', '.join(JOINT_SOURCES)}, got {joints!r}")
        log = result.log
        source = log.joint_q_ref_rad if joints == "reference" else log.joint_q_rad
        if result.start_joints_rad is None or not np.isfinite(source).all():
            raise ValueError(f"this writing result has no {joints} joints to export")
        time_s = np.concatenate([[0.0], log.time_s])
        if joints == "measured":
            q = np.vstack([result.start_joints_rad, log.joint_q_rad])
            qd = np.vstack([np.zeros(7), log.joint_qd_rad_s])
        else:
            q_ref = reference_at_tip_depth(
                result.scene_config,
                source,
                log.tip_m[:, 2],
                log.force_n > 0.0,
                1.0 / float(result.metrics["control_rate_hz"]),
            )
            q = np.vstack([result.start_joints_rad, q_ref])
            qd = np.zeros_like(q)  # [N, 7]
            qd[1:] = np.diff(q, axis=0) / np.diff(time_s)[:, None]
        return cls(
            time_s=time_s,
            position_rad=q,
            velocity_rad_s=qd,
            control_rate_hz=float(result.metrics["control_rate_hz"]),
            scene=dataclasses.asdict(result.scene_config),
            joints=joints,
        )

    @property
    def n_samples(self) -> int:
        return len(self.time_s)

    def limit_violation(self) -> str | None:
        """The first sample outside the iiwa's position or velocity limits in words (the
        joint, the value, the time and the limit), or None if every sample is inside."""
        for kind, values, limits, unit in (
            ("position", self.position_rad, IIWA_POSITION_LIMITS_RAD, "rad"),
            ("velocity", self.velocity_rad_s, IIWA_VELOCITY_LIMITS_RAD_S, "rad/s"),
        ):
            over = np.abs(values) > limits  # [N, 7]
            if over.any():
                i, j = np.argwhere(over)[0]
                return (
                    f"{self.joint_names[j]} {kind} {values[i, j]:.4f} {unit} at "
                    f"t = {self.time_s[i]:.4f} s exceeds the iiwa's limit of "
                    f"±{limits[j]:.4f} {unit} ({math.degrees(limits[j]):.0f} deg"
                    f"{'/s' if kind == 'velocity' else ''})"
                )
        return None

    def acceleration_rad_s2(self) -> np.ndarray:
        """``[N, 7]`` joint accelerations a position-controlled iiwa replaying this
        trajectory is asked for: the finite differences of the velocities over the time
        stamps, the first 0 (the start posture at rest)."""
        qdd = np.zeros_like(self.velocity_rad_s)  # [N, 7]
        if self.n_samples > 1:
            qdd[1:] = np.diff(self.velocity_rad_s, axis=0) / np.diff(self.time_s)[:, None]
        return qdd

    def acceleration_peak(self) -> dict:
        """The largest joint acceleration against its limit
        (``IIWA_ACCELERATION_LIMITS_RAD_S2``): ``{"joint", "acceleration_rad_s2" (signed),
        "time_s", "limit_rad_s2", "share"}`` (the JSON file's ``acceleration_peak``)."""
        qdd = self.acceleration_rad_s2()
        ratio = np.abs(qdd) / IIWA_ACCELERATION_LIMITS_RAD_S2  # [N, 7]
        i, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        return {
            "joint": self.joint_names[j],
            "acceleration_rad_s2": float(qdd[i, j]),
            "time_s": float(self.time_s[i]),
            "limit_rad_s2": float(IIWA_ACCELERATION_LIMITS_RAD_S2[j]),
            "share": float(ratio[i, j]),
        }

    def acceleration_violation(self) -> str | None:
        """The largest joint acceleration over its limit in words (the joint, the value,
        the time and the limit), or None if every sample is within. A warning, not a
        refusal: the limit is a planner's (KUKA publishes none), and what the simulated arm
        adds to the plan while it writes (its tracking of a DMP's own accelerations, the
        pen's friction on the paper at a stroke's sharp turns) stays within a few tens of
        per cent of it (docs/ROBOT.md)."""
        peak = self.acceleration_peak()
        if peak["share"] <= 1.0:
            return None
        return (
            f"{peak['joint']} acceleration {peak['acceleration_rad_s2']:.2f} rad/s^2 at "
            f"t = {peak['time_s']:.4f} s exceeds the planning limit of "
            f"±{peak['limit_rad_s2']:g} rad/s^2 ({100 * peak['share']:.0f} % of it)"
        )

    def check_limits(self, where: str = "joint trajectory") -> None:
        """``ValueError`` naming ``where``, the joint, the time, the value and the limit at
        the first sample outside the iiwa's position or velocity limits
        (:meth:`limit_violation`)."""
        violation = self.limit_violation()
        if violation is not None:
            raise ValueError(f"{where}: {violation}; nothing written")

    def to_json(self) -> str:
        doc = {
            "format": FORMAT,
            "version": VERSION,
            "robot": ROBOT,
            "joint_names": list(self.joint_names),
            "control_rate_hz": self.control_rate_hz,
            "units": {"time": "s", "position": "rad", "velocity": "rad/s"},
            "limits": {
                "position_rad": [[-v, v] for v in IIWA_POSITION_LIMITS_RAD.tolist()],
                "velocity_rad_s": IIWA_VELOCITY_LIMITS_RAD_S.tolist(),
                "acceleration_rad_s2": IIWA_ACCELERATION_LIMITS_RAD_S2.tolist(),
            },
            "acceleration_peak": self.acceleration_peak(),
            "scene": self.scene,
            "joints": self.joints,
            "time_s": np.round(self.time_s, 9).tolist(),
            "position_rad": np.round(self.position_rad, 10).tolist(),
            "velocity_rad_s": np.round(self.velocity_rad_s, 8).tolist(),
        }
        return json.dumps(doc)

    def to_csv(self) -> str:
        f = io.StringIO(newline="")
        w = csv.writer(f)
        w.writerow(
            ["time_s"]
            + [f"{n}_rad" for n in self.joint_names]
            + [f"{n}_rad_s" for n in self.joint_names]
        )
        for t, q, qd in zip(self.time_s, self.position_rad, self.velocity_rad_s, strict=True):
            w.writerow([f"{t:.6f}", *(f"{v:.10f}" for v in q), *(f"{v:.8f}" for v in qd)])
        return f.getvalue()


def export_paths(path) -> tuple[str, str]:
    """The CSV and JSON files of ``--export-joints path``: ``path`` without a ``.csv`` or
    ``.json`` suffix, then each suffix."""
    base = os.fspath(path)
    root, ext = os.path.splitext(base)
    if ext.lower() in SUFFIXES:
        base = root
    return base + ".csv", base + ".json"


def save_joint_trajectory(trajectory: JointTrajectory, path) -> tuple[str, str]:
    """Check ``trajectory`` against the iiwa's limits (``ValueError`` naming the file, the
    joint and the value; nothing written), then write it as CSV and JSON (atomically) to
    :func:`export_paths` of ``path``; return the two paths."""
    csv_path, json_path = export_paths(path)
    trajectory.check_limits(f"{json_path}: joint trajectory")
    atomic_write_text(json_path, trajectory.to_json())
    atomic_write_text(csv_path, trajectory.to_csv())
    return csv_path, json_path


def _field(doc: dict, name: str, path) -> object:
    if name not in doc:
        raise ValueError(f"{path}: field '{name}' is missing")
    return doc[name]


def _array(doc: dict, name: str, shape: tuple, path) -> np.ndarray:
    value = _field(doc, name, path)
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        a = None
    ok = a is not None and a.ndim == len(shape) and a.shape[1:] == shape[1:] and len(a) > 0
    if not ok or not np.isfinite(a).all():
        what = "[N]" if len(shape) == 1 else "[N][7]"
        raise ValueError(f"{path}: field '{name}' must be {what} finite numbers")
    return a


def load_joint_trajectory(path) -> JointTrajectory:
    """Read a trajectory written by :func:`save_joint_trajectory` (the JSON file);
    ``ValueError`` naming the file and the field for anything else."""
    with open(path, encoding="utf-8") as f:
        try:
            doc = json.load(f)
        except json.JSONDecodeError as e:
            raise ValueError(f"{path}: not JSON ({e})") from e
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{path}: field 'format' must be {FORMAT!r}")
    version = _field(doc, "version", path)
    if type(version) is not int or version != VERSION:
        raise ValueError(f"{path}: field 'version' must be {VERSION}, got {doc['version']!r}")
    time_s = _array(doc, "time_s", (1,), path)
    q = _array(doc, "position_rad", (1, 7), path)
    qd = _array(doc, "velocity_rad_s", (1, 7), path)
    if not (len(q) == len(qd) == len(time_s)) or np.any(np.diff(time_s) <= 0):
        raise ValueError(
            f"{path}: fields 'time_s', 'position_rad', 'velocity_rad_s' must have one entry "
            "per sample, at increasing times"
        )
    names = _field(doc, "joint_names", path)
    if names != list(IIWA_JOINT_NAMES):
        raise ValueError(f"{path}: field 'joint_names' must be {list(IIWA_JOINT_NAMES)}")
    rate = _field(doc, "control_rate_hz", path)
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate < math.inf:
        raise ValueError(f"{path}: field 'control_rate_hz' must be a number > 0, got {rate!r}")
    scene = _field(doc, "scene", path)
    try:
        SceneConfig(**_scene_fields(scene))
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: field 'scene' is not a SceneConfig ({e})") from e
    joints = doc.get("joints", "measured")  # what the files before the field held
    if joints not in JOINT_SOURCES:
        raise ValueError(f"{path}: field 'joints' must be one of {list(JOINT_SOURCES)}, "
                         f"got {joints!r}")  # fmt: skip
    return JointTrajectory(time_s, q, qd, tuple(names), float(rate), dict(scene), joints)


def _smootherstep(u: np.ndarray) -> np.ndarray:
    """0 to 1 over ``u`` in [0, 1] with zero first and second derivatives at both ends
    (``10 u^3 - 15 u^4 + 6 u^5``): a ramp that adds no step to the acceleration."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2)


def depth_offset_m(offset_m, touching, dt_s: float) -> np.ndarray:
    """``[S]``: the offset along the pen that the reference gets, from the measured one.

    ``offset_m [S]`` is the tip's measured height minus the reference's, ``touching [S]``
    whether the pen touched the paper after each step. While it touched (spans of contact
    closer than :data:`DEPTH_CONTACT_GAP_S` joined) the offset is the measured one; off
    the paper it is 0 (the reference as the IK solved it: in the air the measured offset
    is the torque-controlled arm's lag, up to 0.45 mm at 240 Hz, with a kink at each
    touch-down and lift-off that would be replayed as jerk), brought in before a
    touch-down and out after a lift-off by a quintic ramp of :data:`DEPTH_RAMP_S` (from
    one touch to the next directly when they are closer than two ramps). The whole is
    then low-passed without delay (a 2nd-order Butterworth at :data:`DEPTH_CUTOFF_HZ`
    forwards and backwards), which takes out the contact's step-to-step noise (the pen's
    spring and the admittance loop; 1.1 um RMS third differences at 240 Hz) and the
    rise at touch-down: the replayed pen lands, presses the set force and lifts as in
    the run. No contact at all: 0."""
    offset_m = np.asarray(offset_m, dtype=float)
    n = len(offset_m)
    out = np.zeros(n)  # [S]
    spans: list[list[int]] = []
    for a, b in stroke_spans(np.asarray(touching, dtype=bool)):
        if spans and (a - spans[-1][1] - 1) * dt_s < DEPTH_CONTACT_GAP_S:
            spans[-1][1] = b
        else:
            spans.append([a, b])
    if not spans:
        return out
    ramp = max(1, round(DEPTH_RAMP_S / dt_s))
    end, value = -1, 0.0  # the start posture (before step 0) has no offset
    for a, b in spans:
        i = np.arange(end + 1, a)  # the steps in the air before this touch
        if a - end - 1 >= 2 * ramp:
            out[i] = value * (1.0 - _smootherstep((i - end) / ramp))
            out[i] += offset_m[a] * _smootherstep((i - (a - ramp)) / ramp)
        else:
            out[i] = value + (offset_m[a] - value) * _smootherstep((i - end) / (a - end))
        out[a : b + 1] = offset_m[a : b + 1]
        end, value = b, offset_m[b]
    i = np.arange(end + 1, n)
    out[i] = value * (1.0 - _smootherstep((i - end) / ramp))
    padded = np.concatenate([[0.0], out])  # from the start posture
    return _low_pass_both_ways(padded, DEPTH_CUTOFF_HZ * dt_s, min(9, len(padded) - 1))[1:]


def _butterworth2(cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """The 2nd-order Butterworth low-pass at ``cutoff`` (cycles per sample, below 0.5):
    ``(b, a)`` of the bilinear transform with the cut-off prewarped, as
    ``scipy.signal.butter(2, cutoff, fs=1)`` designs it (whose import raised a page's
    ``write --export-joints`` from 234 to 254 MiB of peak memory)."""
    k = math.tan(math.pi * cutoff)
    norm = 1.0 / (1.0 + math.sqrt(2.0) * k + k * k)
    b = np.array([k * k, 2.0 * k * k, k * k]) * norm
    a = np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - math.sqrt(2.0) * k + k * k) * norm])
    return b, a


def _biquad(b: np.ndarray, a: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``x`` through the biquad ``(b, a)`` (transposed direct form II) from state ``z``."""
    y = np.empty_like(x)
    z0, z1 = float(z[0]), float(z[1])
    b0, b1, b2, a1, a2 = float(b[0]), float(b[1]), float(b[2]), float(a[1]), float(a[2])
    for i, v in enumerate(x.tolist()):
        out = b0 * v + z0
        z0 = b1 * v - a1 * out + z1
        z1 = b2 * v - a2 * out
        y[i] = out
    return y


def _low_pass_both_ways(x: np.ndarray, cutoff: float, padlen: int) -> np.ndarray:
    """``x`` low-passed forwards and backwards (no delay; :func:`_butterworth2`), as
    ``scipy.signal.sosfiltfilt`` does: ``padlen`` samples of odd extension at each end,
    each pass started from the filter's steady state for its first sample."""
    b, a = _butterworth2(cutoff)
    # the state that a constant input of 1 leaves (scipy.signal.lfilter_zi)
    companion = np.array([[-a[1], 1.0], [-a[2], 0.0]])
    zi = np.linalg.solve(np.eye(2) - companion, b[1:] - a[1:] * b[0])
    if padlen > 0:
        x = np.concatenate([2 * x[0] - x[padlen:0:-1], x, 2 * x[-1] - x[-2 : -padlen - 2 : -1]])
    y = _biquad(b, a, x, zi * x[0])
    y = _biquad(b, a, y[::-1].copy(), zi * y[-1])[::-1]
    return y[padlen : len(y) - padlen] if padlen > 0 else y


def reference_at_tip_depth(
    scene_config: SceneConfig, q_ref_rad, tip_z_m, touching, dt_s: float
) -> np.ndarray:
    """``[S, 7]``: the controller's joint reference ``q_ref_rad [S, 7]`` moved along the
    pen (world z, the pen held vertical) so that the tip stands at the measured tip
    heights ``tip_z_m [S]`` while the pen touched the paper (``touching [S]``), with the
    same point in the plane and the same orientation; the offset smoothed and kept to
    the contact by :func:`depth_offset_m` (``dt_s`` the control period).

    The reference puts the tip at the admittance law's commanded height, which lies
    below the pen's measured depth by what the torque-controlled arm yields to the
    contact force: replayed by a stiff position servo it pressed 8.0 N instead of the
    5 N set (docs/ROBOT.md). Each sample is moved by the minimum-norm joint step
    ``dq = J^T (J J^T)^-1 [0, 0, dz, 0, 0, 0]`` (``J`` the tip's 6 x 7 Jacobian at the
    reference on the kinematic twin, ``dz`` the offset, a fraction of a millimetre:
    first order is exact to nanometres)."""
    q_ref = np.asarray(q_ref_rad, dtype=float)
    out = q_ref.copy()  # [S, 7]
    jacobians = np.zeros((len(q_ref), 6, 7))
    offset_m = np.zeros(len(q_ref))  # [S]
    with WritingScene(scene_config) as scene:
        for i, q in enumerate(q_ref):
            offset_m[i] = float(tip_z_m[i]) - scene.tip_pose_at(q)[0][2]
            jacobians[i] = scene.tip_jacobian(q)
    e = np.zeros(6)
    for i, dz in enumerate(depth_offset_m(offset_m, touching, dt_s)):
        e[2] = dz
        jac = jacobians[i]
        out[i] = q_ref[i] + jac.T @ np.linalg.solve(jac @ jac.T, e)
    return out


@dataclass
class Replay:
    """What a replay produced, one entry per sample after the first (N - 1 steps)."""

    time_s: np.ndarray  # [N-1]
    tip_m: np.ndarray  # [N-1, 3]
    force_n: np.ndarray  # [N-1]
    joint_q_rad: np.ndarray  # [N-1, 7]

    def ink_m(self) -> np.ndarray:
        """Where the pen wrote: the tip's path while touching, as points ``[m, 2]``."""
        return ink_points(self.tip_m[:, :2], self.force_n > 0.0)


def replay_joint_trajectory(
    trajectory: JointTrajectory,
    scene_config: SceneConfig | None = None,
    *,
    position_gain: float = 1.0,
    velocity_gain: float = 1.0,
) -> Replay:
    """Play ``trajectory`` back in a fresh simulated cell by joint position control.

    The arm starts at rest at the first sample; each later sample is one physics step
    of pybullet's position servo (:meth:`WritingScene.step_positions`) towards that
    sample's positions and velocities. ``scene_config``: the cell (default: the one
    recorded in the trajectory). ``ValueError`` for samples that are not one period of
    ``control_rate_hz`` apart.
    """
    dt_s = 1.0 / trajectory.control_rate_hz
    steps = np.diff(trajectory.time_s)
    if len(steps) and np.max(np.abs(steps - dt_s)) > 1e-6 * dt_s + 1e-9:
        raise ValueError(
            f"the trajectory's samples must be 1 / control_rate_hz = {dt_s:.6g} s apart to "
            f"be replayed, got steps from {steps.min():.6g} to {steps.max():.6g} s"
        )
    if scene_config is None:
        scene_config = SceneConfig(**_scene_fields(trajectory.scene))
    n = trajectory.n_samples - 1
    tip, force, q_out = np.zeros((n, 3)), np.zeros(n), np.zeros((n, 7))
    with WritingScene(scene_config, time_step_s=dt_s) as scene:
        scene.reset_joints(trajectory.position_rad[0])
        for i in range(n):
            scene.step_positions(
                trajectory.position_rad[i + 1],
                trajectory.velocity_rad_s[i + 1],
                position_gain=position_gain,
                velocity_gain=velocity_gain,
            )
            tip[i] = scene.tip_pose()[0]
            force[i] = scene.contact_force_n()
            q_out[i] = scene.joint_state()[0]
    return Replay(trajectory.time_s[1:], tip, force, q_out)


def _scene_fields(scene) -> dict:
    """SceneConfig keyword arguments from a JSON record (lists back to tuples)."""
    if not isinstance(scene, dict):
        raise TypeError(f"a JSON object is needed, got {type(scene).__name__}")
    return {k: tuple(v) if isinstance(v, list) else v for k, v in scene.items()}
