"""The simulated writing cell: a KUKA LBR iiwa with a pen, a table and a sheet of paper.

Frames (all in metres, world frame = robot base frame):

- world: origin at the robot's base on the table top, z up, x away from the robot
  towards the paper;
- table top at ``z = 0``; the paper is a thin static box whose top surface lies at
  ``z = paper_top_z``;
- the pen is fixed to the flange of ``lbr_iiwa_link_7`` along the flange's z axis; the
  link ``pen_tip`` sits **at the very tip** with its centre of mass at its own origin,
  because pybullet's inverse kinematics and ``getLinkState`` report a link's centre of
  mass, not its URDF frame.

The robot model is pybullet_data's ``kuka_iiwa/model.urdf`` with two links appended (pen
body and tip), written to a temporary file whose mesh paths point back into pybullet_data,
removed as soon as pybullet has read it (a process killed later leaves nothing behind).
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass

import numpy as np

from ..config import check_positive_fields
from . import _pybullet

# A comfortable writing posture: elbow up, wrist above the paper, pen vertical.
HOME_JOINTS_RAD = (0.0, 0.55, 0.0, -1.6, 0.0, 1.0, 0.0)
FLANGE_OFFSET_M = 0.045  # joint 7 frame to the flange face, along the flange's z axis


@dataclass(frozen=True)
class SceneConfig:
    """Geometry and contact properties of the writing cell.

    Parameters
    ----------
    paper_center_m : tuple of float
        (x, y) of the centre of the sheet in the world frame, metres.
    paper_size_m : tuple of float
        Sheet size along world x and y, metres (default A5, 0.148 x 0.21).
    paper_thickness_m : float
        Thickness of the (rigid) sheet.
    pen_length_m : float
        Flange face to pen tip.
    pen_tip_radius_m : float
        Radius of the spherical tip that touches the paper.
    contact_stiffness_n_per_m, contact_damping_n_s_per_m : float
        Soft contact of tip and paper (the felt tip and paper give a little); 5 N then
        presses the tip ``5 / stiffness`` metres into the sheet.
    friction : float
        Coulomb friction coefficient of tip on paper.
    """

    paper_center_m: tuple[float, float] = (0.55, 0.0)
    paper_size_m: tuple[float, float] = (0.148, 0.21)
    paper_thickness_m: float = 0.001
    pen_length_m: float = 0.15
    pen_tip_radius_m: float = 0.0015
    contact_stiffness_n_per_m: float = 2.0e4
    contact_damping_n_s_per_m: float = 300.0
    friction: float = 0.2

    def __post_init__(self) -> None:
        names = ("paper_thickness_m", "pen_length_m", "pen_tip_radius_m")
        check_positive_fields(
            self, (*names, "contact_stiffness_n_per_m", "contact_damping_n_s_per_m")
        )
        if len(self.paper_center_m) != 2 or not all(map(math.isfinite, self.paper_center_m)):
            raise ValueError(
                f"paper_center_m must be two finite numbers, got {self.paper_center_m}"
            )
        if len(self.paper_size_m) != 2 or not all(s > 0 for s in self.paper_size_m):
            raise ValueError(f"paper_size_m must be two numbers > 0, got {self.paper_size_m}")
        if not (math.isfinite(self.friction) and self.friction >= 0):
            raise ValueError(f"friction must be a finite number >= 0, got {self.friction!r}")

    @property
    def paper_top_z(self) -> float:
        """Height of the writing surface, metres."""
        return self.paper_thickness_m


def _pen_urdf(pen_length_m: float, tip_radius_m: float) -> str:
    """URDF text of the pen links, appended to link 7 of the iiwa."""
    body_len = pen_length_m - 0.01  # the last centimetre is the conical tip
    tip_z = FLANGE_OFFSET_M + pen_length_m
    return f"""
  <joint name="pen_mount" type="fixed">
    <parent link="lbr_iiwa_link_7"/>
    <child link="pen_body"/>
    <origin rpy="0 0 0" xyz="0 0 {FLANGE_OFFSET_M + body_len / 2:.6f}"/>
  </joint>
  <link name="pen_body">
    <inertial>
      <origin rpy="0 0 0" xyz="0 0 0"/>
      <mass value="0.02"/>
      <inertia ixx="4e-5" ixy="0" ixz="0" iyy="4e-5" iyz="0" izz="4e-7"/>
    </inertial>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 0"/>
      <geometry><cylinder length="{body_len:.6f}" radius="0.006"/></geometry>
      <material name="PenBlue"><color rgba="0.1 0.25 0.8 1"/></material>
    </visual>
  </link>
  <joint name="pen_tip_mount" type="fixed">
    <parent link="lbr_iiwa_link_7"/>
    <child link="pen_tip"/>
    <origin rpy="0 0 0" xyz="0 0 {tip_z:.6f}"/>
  </joint>
  <link name="pen_tip">
    <inertial>
      <origin rpy="0 0 0" xyz="0 0 0"/>
      <mass value="0.002"/>
      <inertia ixx="1e-7" ixy="0" ixz="0" iyy="1e-7" iyz="0" izz="1e-7"/>
    </inertial>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 -0.005"/>
      <geometry><cylinder length="0.01" radius="0.002"/></geometry>
      <material name="Ink"><color rgba="0.05 0.05 0.1 1"/></material>
    </visual>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 {-tip_radius_m:.6f}"/>
      <geometry><sphere radius="{tip_radius_m:.6f}"/></geometry>
    </collision>
  </link>
"""


def robot_urdf_path(pen_length_m: float, tip_radius_m: float, directory: str) -> str:
    """Write the iiwa-with-pen URDF into ``directory`` and return its path."""
    p, pybullet_data = _pybullet.require()
    del p
    src_dir = os.path.join(pybullet_data.getDataPath(), "kuka_iiwa")
    with open(os.path.join(src_dir, "model.urdf"), encoding="utf-8") as f:
        text = f.read()
    text = text.replace('filename="meshes/', f'filename="{src_dir}/meshes/')
    end = text.rindex("</robot>")
    text = text[:end] + _pen_urdf(pen_length_m, tip_radius_m) + text[end:]
    path = os.path.join(directory, "iiwa_pen.urdf")
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
    return path


_EYE6, _EYE7 = np.eye(6), np.eye(7)


def _half_column_cross_sum(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``1/2 sum_i a_i x b_i`` over the columns of two 3 x 3 matrices (the IK's orientation
    error): ``0.5 * np.cross(a, b, axis=0).sum(axis=1)``, the same numbers, written out
    (``np.cross`` with an axis was a third of a solve's time)."""
    return 0.5 * np.array([
        (a[1] * b[2] - a[2] * b[1]).sum(),
        (a[2] * b[0] - a[0] * b[2]).sum(),
        (a[0] * b[1] - a[1] * b[0]).sum(),
    ])  # fmt: skip


class WritingScene:
    """A headless pybullet world (``p.DIRECT``) holding the arm, the table and the paper.

    A second, kinematics-only pybullet client holds a copy of the arm for inverse
    kinematics (:meth:`solve_ik`), so that solving never disturbs the simulated robot.

    Parameters
    ----------
    config : SceneConfig
        Geometry and contact properties.
    time_step_s : float
        Physics time step (the controller runs once per step).
    """

    def __init__(self, config: SceneConfig | None = None, *, time_step_s: float = 1.0 / 240.0):
        p, pybullet_data = _pybullet.require()
        self.p = p
        self.config = config or SceneConfig()
        if not (math.isfinite(time_step_s) and 0 < time_step_s <= 0.01):
            raise ValueError(f"time_step_s must be in (0, 0.01] seconds, got {time_step_s!r}")
        self.time_step_s = float(time_step_s)
        cfg = self.config
        self.client = p.connect(p.DIRECT)
        self.ik_client = p.connect(p.DIRECT)
        c = self.client
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
        p.setGravity(0, 0, -9.81, physicsClientId=c)
        p.setTimeStep(self.time_step_s, physicsClientId=c)
        p.setPhysicsEngineParameter(numSolverIterations=50, physicsClientId=c)

        self.table_id = self._box(
            half_extents=(0.6, 0.6, 0.375),
            position=(0.35, 0.0, -0.375),
            rgba=(0.55, 0.38, 0.22, 1.0),
        )
        px, py = cfg.paper_center_m
        sx, sy = cfg.paper_size_m
        self.paper_id = self._box(
            half_extents=(sx / 2, sy / 2, cfg.paper_thickness_m / 2),
            position=(px, py, cfg.paper_thickness_m / 2),
            rgba=(0.97, 0.97, 0.95, 1.0),
        )
        self.robot_id, self.ik_robot_id = self._load_robot()
        self.joint_ids, self.tip_link, self.pen_link = self._index_joints()
        info = [p.getJointInfo(self.robot_id, j, physicsClientId=c) for j in self.joint_ids]
        self.joint_names = tuple(i[1].decode() for i in info)
        self.lower_rad = np.array([i[8] for i in info])
        self.upper_rad = np.array([i[9] for i in info])
        self.max_torque_nm = np.array([i[10] for i in info])
        p.changeDynamics(
            self.robot_id,
            self.tip_link,
            lateralFriction=cfg.friction,
            contactStiffness=cfg.contact_stiffness_n_per_m,
            contactDamping=cfg.contact_damping_n_s_per_m,
            physicsClientId=c,
        )
        p.changeDynamics(self.paper_id, -1, lateralFriction=cfg.friction, physicsClientId=c)
        # The URDF's joint damping (0.5 N m s) is applied explicitly by the engine; on the
        # light wrist (about 0.0015 kg m^2) it adds to the controller's damping until the
        # explicit step goes unstable and joint 7 spins. The controller damps instead.
        for link in range(p.getNumJoints(self.robot_id, physicsClientId=c)):
            p.changeDynamics(
                self.robot_id,
                link,
                jointDamping=0.0,
                linearDamping=0.0,
                angularDamping=0.0,
                physicsClientId=c,
            )
        # Torque control: the default velocity motors must release the joints.
        p.setJointMotorControlArray(
            self.robot_id,
            self.joint_ids,
            p.VELOCITY_CONTROL,
            forces=[0.0] * len(self.joint_ids),
            physicsClientId=c,
        )
        self.reset_joints(np.array(HOME_JOINTS_RAD))
        self._ink_ids: list[int] = []

    # -- construction helpers -------------------------------------------------------------
    def _load_robot(self) -> tuple[int, int]:
        """The arm with its pen in both clients (ids), from a URDF in a temporary folder
        removed as soon as pybullet has read it: pybullet keeps no reference to the file
        (its meshes are pybullet_data's), and a process killed while it writes (e.g. a
        robot run of a server that stops) would otherwise leave the folder in /tmp."""
        p, cfg, flags = self.p, self.config, self.p.URDF_USE_INERTIA_FROM_FILE
        with tempfile.TemporaryDirectory(prefix="img2dmp-robot-") as tmp:
            urdf = robot_urdf_path(cfg.pen_length_m, cfg.pen_tip_radius_m, tmp)
            return tuple(p.loadURDF(urdf, useFixedBase=True, flags=flags, physicsClientId=c)
                         for c in (self.client, self.ik_client))  # fmt: skip

    def _box(self, half_extents, position, rgba) -> int:
        p, c = self.p, self.client
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half_extents, physicsClientId=c)
        vis = p.createVisualShape(
            p.GEOM_BOX, halfExtents=half_extents, rgbaColor=rgba, physicsClientId=c
        )
        return p.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=col,
            baseVisualShapeIndex=vis,
            basePosition=position,
            physicsClientId=c,
        )

    def _index_joints(self):
        p, c = self.p, self.client
        joints, tip, pen = [], None, None
        for j in range(p.getNumJoints(self.robot_id, physicsClientId=c)):
            info = p.getJointInfo(self.robot_id, j, physicsClientId=c)
            if info[2] == p.JOINT_REVOLUTE:
                joints.append(j)
            name = info[12].decode()
            if name == "pen_tip":
                tip = j
            elif name == "pen_body":
                pen = j
        if len(joints) != 7 or tip is None:
            raise RuntimeError("the iiwa-with-pen model did not load as expected")
        return joints, tip, pen

    # -- state ----------------------------------------------------------------------------
    def close(self) -> None:
        """Disconnect both pybullet clients."""
        for cid in (self.client, self.ik_client):
            try:
                self.p.disconnect(physicsClientId=cid)
            except Exception:  # noqa: BLE001 - already disconnected
                pass

    def __enter__(self) -> WritingScene:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def reset_joints(self, q_rad: np.ndarray) -> None:
        """Teleport the simulated arm (before the simulation starts) to ``q_rad``, at rest."""
        for j, qj in zip(self.joint_ids, q_rad, strict=True):
            self.p.resetJointState(self.robot_id, j, float(qj), 0.0, physicsClientId=self.client)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions (rad) and velocities (rad/s) of the simulated arm."""
        states = self.p.getJointStates(self.robot_id, self.joint_ids, physicsClientId=self.client)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def tip_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Pen-tip position (m) and the pen axis (unit vector from flange to tip)."""
        s = self.p.getLinkState(
            self.robot_id, self.tip_link, computeForwardKinematics=True, physicsClientId=self.client
        )
        rot = np.array(self.p.getMatrixFromQuaternion(s[5])).reshape(3, 3)
        return np.array(s[4]), rot[:, 2]

    def contact_force_n(self) -> float:
        """Normal force between the pen tip and the paper, newtons (0 without contact)."""
        pts = self.p.getContactPoints(
            bodyA=self.robot_id,
            bodyB=self.paper_id,
            linkIndexA=self.tip_link,
            physicsClientId=self.client,
        )
        return float(sum(pt[9] for pt in pts))

    def step(self, torques_nm: np.ndarray) -> None:
        """Apply joint torques for one time step and advance the physics."""
        p, c = self.p, self.client
        p.setJointMotorControlArray(
            self.robot_id,
            self.joint_ids,
            p.TORQUE_CONTROL,
            forces=[float(t) for t in torques_nm],
            physicsClientId=c,
        )
        p.stepSimulation(physicsClientId=c)

    def step_positions(
        self, q_rad, qd_rad_s, *, position_gain: float = 1.0, velocity_gain: float = 1.0
    ) -> None:
        """Drive the joints towards ``q_rad`` at ``qd_rad_s`` with pybullet's joint position
        servo (``POSITION_CONTROL``, torques up to ``max_torque_nm``) for one time step and
        advance the physics: how a position-controlled arm replays a joint trajectory.
        The gains are the servo's (1, 1: reach the target within the step if it can)."""
        p, c = self.p, self.client
        n = len(self.joint_ids)
        p.setJointMotorControlArray(
            self.robot_id,
            self.joint_ids,
            p.POSITION_CONTROL,
            targetPositions=[float(v) for v in q_rad],
            targetVelocities=[float(v) for v in qd_rad_s],
            forces=[float(t) for t in self.max_torque_nm],
            positionGains=[float(position_gain)] * n,
            velocityGains=[float(velocity_gain)] * n,
            physicsClientId=c,
        )
        p.stepSimulation(physicsClientId=c)

    def inverse_dynamics(self, q, qd, qdd) -> np.ndarray:
        """Joint torques ``M(q) qdd + C(q, qd) qd + g(q)`` (pybullet's RNEA)."""
        tau = self.p.calculateInverseDynamics(
            self.robot_id,
            list(map(float, q)),
            list(map(float, qd)),
            list(map(float, qdd)),
            physicsClientId=self.client,
        )
        return np.array(tau)

    # -- kinematics on the twin ------------------------------------------------------------
    def tip_pose_at(self, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics on the twin: tip position (m) and rotation matrix at ``q_rad``."""
        p, c, rid = self.p, self.ik_client, self.ik_robot_id
        values = [[float(qj)] for qj in q_rad]
        if len(values) != len(self.joint_ids):
            raise ValueError(f"q_rad has {len(values)} joint angles, the arm {len(self.joint_ids)}")
        p.resetJointStatesMultiDof(rid, self.joint_ids, values, physicsClientId=c)  # one call
        s = p.getLinkState(rid, self.tip_link, computeForwardKinematics=True, physicsClientId=c)
        return np.array(s[4]), np.array(p.getMatrixFromQuaternion(s[5])).reshape(3, 3)

    def tip_jacobian(self, q_rad: np.ndarray) -> np.ndarray:
        """Geometric Jacobian ``[6, 7]`` (linear; angular) of the pen tip at ``q_rad``."""
        p, c, rid = self.p, self.ik_client, self.ik_robot_id
        q = list(map(float, q_rad))
        lin, ang = p.calculateJacobian(
            rid, self.tip_link, [0.0, 0.0, 0.0], q, [0.0] * 7, [0.0] * 7, physicsClientId=c
        )
        return np.array(lin + ang)  # [6, 7]: the linear rows, then the angular

    def solve_ik(
        self,
        position_m,
        rotation: np.ndarray,
        seed_rad: np.ndarray,
        *,
        tol_m: float = 1e-6,
        max_iterations: int = 30,
        damping: float = 1e-3,
        posture_gain: float = 0.1,
        min_iterations: int = 0,
    ) -> tuple[np.ndarray, float]:
        """Joint angles that put the pen tip at ``position_m`` with orientation ``rotation``.

        Damped least squares on the kinematic twin, started from ``seed_rad``:
        ``dq = J^T (J J^T + damping^2 I)^-1 e`` with the 6-D pose error ``e`` (position;
        orientation as ``1/2 sum_i r_i x r_i^d`` over the columns of the rotation
        matrices), plus a step towards the home posture in the null space of ``J``
        (the iiwa has one redundant joint). pybullet's own solver is not used: with
        joint limits and a rest pose it leaves millimetres of residual.

        ``min_iterations``: iterations taken even when ``seed_rad`` is within ``tol_m``
        already (the controller takes one every control step, so its reference moves
        with a target that moves less than ``tol_m`` per step, instead of standing and
        then catching up).

        Returns
        -------
        q_rad : ndarray [7]
            Clipped to the joint limits.
        residual_m : float
            Distance between the requested and the reached tip position.
        """
        target = np.asarray(position_m, dtype=float)
        rot_d = np.asarray(rotation, dtype=float)
        q = np.asarray(seed_rad, dtype=float).copy()
        home = np.asarray(HOME_JOINTS_RAD)
        residual = math.inf
        damp = damping**2 * _EYE6
        for k in range(max_iterations):
            pos, rot = self.tip_pose_at(q)
            e_pos = target - pos
            e_rot = _half_column_cross_sum(rot, rot_d)
            residual = math.sqrt(e_pos @ e_pos)  # np.linalg.norm's own sum, without its checks
            if k >= min_iterations and residual < tol_m and math.sqrt(e_rot @ e_rot) < 1e-5:
                break
            jac = self.tip_jacobian(q)
            jjt = jac @ jac.T + damp
            dq = jac.T @ np.linalg.solve(jjt, np.concatenate([e_pos, e_rot]))
            null = _EYE7 - jac.T @ np.linalg.solve(jjt, jac)
            q = np.clip(q + dq + posture_gain * null @ (home - q), self.lower_rad, self.upper_rad)
        else:
            pos, _ = self.tip_pose_at(q)
            residual = float(np.linalg.norm(target - pos))
        return q, residual

    # -- ink and pictures -----------------------------------------------------------------
    def add_ink(self, points_m: np.ndarray, radius_m: float = 0.0008) -> None:
        """Draw visual-only dots (no collision, no mass) on the paper at ``points_m [n, 3]``."""
        p, c = self.p, self.client
        pts = np.asarray(points_m, dtype=float).reshape(-1, 3)
        if len(pts) == 0:
            return
        vis = p.createVisualShape(
            p.GEOM_SPHERE, radius=radius_m, rgbaColor=(0.05, 0.05, 0.35, 1.0), physicsClientId=c
        )
        # One batch call per chunk; pybullet caps the batch size.
        for lo in range(0, len(pts), 256):
            chunk = pts[lo : lo + 256]
            ids = p.createMultiBody(
                baseMass=0.0,
                baseVisualShapeIndex=vis,
                batchPositions=chunk.tolist(),
                physicsClientId=c,
            )
            self._ink_ids.extend(ids if isinstance(ids, (list, tuple)) else [ids])

    def render(
        self,
        width_px: int = 640,
        height_px: int = 480,
        *,
        target_m=(0.45, 0.0, 0.25),
        distance_m: float = 1.5,
        yaw_deg: float = 50.0,
        pitch_deg: float = -30.0,
        fov_deg: float = 45.0,
        shadow: bool = True,
    ) -> np.ndarray:
        """Camera picture (CPU TinyRenderer, works headless) as ``uint8 [H, W, 3]``."""
        p, c = self.p, self.client
        view = p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=list(target_m),
            distance=distance_m,
            yaw=yaw_deg,
            pitch=pitch_deg,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=c,
        )
        proj = p.computeProjectionMatrixFOV(
            fov=fov_deg, aspect=width_px / height_px, nearVal=0.01, farVal=10.0, physicsClientId=c
        )
        img = p.getCameraImage(
            width_px,
            height_px,
            viewMatrix=view,
            projectionMatrix=proj,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=[0.4, -0.6, 1.0],
            shadow=int(shadow),
            physicsClientId=c,
        )
        rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (height_px, width_px, 4))
        return rgba[..., :3].copy()
