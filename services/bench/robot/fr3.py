"""Franka Research 3 holding the instrument: a Pinocchio model built from the modified-DH table.

No robot description package and no URDF: the seven revolute joints are added one by one from
the maker's Craig (modified) DH parameters (`FR3_DH` below). The instrument is fixed to
the flange; the frame "tool" has its origin AT THE INSTRUMENT TIP and its z axis along the shaft,
pointing distally (e_s = e_z, u = R_base_tool @ e_z). Lengths in metres, angles in radians.

`fk_dh` is an independent pure-numpy forward kinematics of the same table, used to test the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

# Modified DH (Craig): T_{i-1,i} = RotX(alpha_i) TransX(a_i) RotZ(q_i) TransZ(d_i).
# Columns: a [m], d [m], alpha [rad].
FR3_DH = np.array(
    [
        [0.0, 0.333, 0.0],
        [0.0, 0.0, -np.pi / 2],
        [0.0, 0.316, np.pi / 2],
        [0.0825, 0.0, np.pi / 2],
        [-0.0825, 0.384, -np.pi / 2],
        [0.0, 0.0, np.pi / 2],
        [0.088, 0.0, np.pi / 2],
    ]
)
FR3_FLANGE_D_M = 0.107
FR3_Q_MIN_RAD = np.array([-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159])
FR3_Q_MAX_RAD = np.array([2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159])
FR3_DQ_MAX_RADPS = np.array([2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26])
N_JOINTS = 7


@dataclass(frozen=True)
class InstrumentMount:
    """Where the instrument sits on the flange, all in flange coordinates.

    The shaft leaves the handle at `p_flange_handle_m` (the handle / clip-on module between flange
    and shaft) along the tool z axis, whose orientation relative to the flange is the rotation
    `rpy_flange_tool_deg` (roll-pitch-yaw, R = Rz(yaw) Ry(pitch) Rx(roll)). The tip is
    `shaft_length_m` further along that axis. Defaults: a straight instrument on the flange axis,
    tip 0.39 m from the flange.
    """

    shaft_length_m: float = 0.34
    p_flange_handle_m: tuple[float, float, float] = (0.0, 0.0, 0.05)
    rpy_flange_tool_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not 0.05 <= self.shaft_length_m <= 0.6:
            raise ValueError(f"shaft_length_m must be in [0.05, 0.6] m, got {self.shaft_length_m}")
        if len(self.p_flange_handle_m) != 3 or len(self.rpy_flange_tool_deg) != 3:
            raise ValueError("p_flange_handle_m and rpy_flange_tool_deg must have 3 elements")

    def T_flange_tool(self) -> np.ndarray:
        """(4, 4) homogeneous transform from tool (tip) coordinates to flange coordinates."""
        R = rpy_to_matrix(np.deg2rad(self.rpy_flange_tool_deg))
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = np.asarray(self.p_flange_handle_m, dtype=float) + self.shaft_length_m * R[:, 2]
        return T


def rpy_to_matrix(rpy_rad) -> np.ndarray:
    """Roll-pitch-yaw [rad] -> R = Rz(yaw) Ry(pitch) Rx(roll), (3, 3)."""
    r, p, y = (float(v) for v in rpy_rad)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _mdh_static(a: float, d: float, alpha: float) -> np.ndarray:
    """RotX(alpha) TransX(a) TransZ(d): the part of a modified-DH link that does not depend on q."""
    ca, sa = np.cos(alpha), np.sin(alpha)
    return np.array([[1.0, 0.0, 0.0, a], [0.0, ca, -sa, -sa * d], [0.0, sa, ca, ca * d], [0.0, 0.0, 0.0, 1.0]])


def build_fr3_model(mount: InstrumentMount | None = None) -> pin.Model:
    """The FR3 + instrument as a pin.Model with frames "flange" and "tool" (origin at the tip)."""
    mount = mount or InstrumentMount()
    model = pin.Model()
    model.name = "fr3_instrument"
    parent = 0
    # Rough link masses (kg) so dynamics calls are well posed; kinematics does not use them.
    masses = (2.9, 2.7, 2.0, 2.4, 2.6, 1.5, 0.5)
    for i in range(N_JOINTS):
        a, d, alpha = FR3_DH[i]
        placement = pin.SE3(_mdh_static(a, d, alpha))
        jid = model.addJoint(
            parent,
            pin.JointModelRZ(),
            placement,
            f"fr3_joint{i + 1}",
            np.array([87.0 if i < 4 else 12.0]),
            np.array([FR3_DQ_MAX_RADPS[i]]),
            np.array([FR3_Q_MIN_RAD[i]]),
            np.array([FR3_Q_MAX_RAD[i]]),
        )
        model.appendBodyToJoint(jid, pin.Inertia.FromSphere(masses[i], 0.06), pin.SE3.Identity())
        model.addFrame(pin.Frame(f"fr3_link{i + 1}", jid, 0, pin.SE3.Identity(), pin.FrameType.BODY))
        parent = jid
    T_j7_flange = np.eye(4)
    T_j7_flange[2, 3] = FR3_FLANGE_D_M
    flange = model.addFrame(pin.Frame("flange", parent, 0, pin.SE3(T_j7_flange), pin.FrameType.OP_FRAME))
    model.addFrame(
        pin.Frame("tool", parent, flange, pin.SE3(T_j7_flange @ mount.T_flange_tool()), pin.FrameType.OP_FRAME)
    )
    return model


def fk_dh(q_rad: np.ndarray, mount: InstrumentMount | None = None) -> np.ndarray:
    """Pure-numpy modified-DH forward kinematics: q (..., 7) -> T_base_tool (..., 4, 4)."""
    q = np.asarray(q_rad, dtype=float)
    if q.shape[-1] != N_JOINTS:
        raise ValueError(f"q_rad must have 7 joint angles in its last axis, got shape {q.shape}")
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
    for i in range(N_JOINTS):
        a, d, alpha = FR3_DH[i]
        ca, sa = np.cos(alpha), np.sin(alpha)
        ct, st = np.cos(q[..., i]), np.sin(q[..., i])
        A = np.zeros(q.shape[:-1] + (4, 4))
        # Craig: [[ct, -st, 0, a], [st ca, ct ca, -sa, -sa d], [st sa, ct sa, ca, ca d], [0 0 0 1]]
        A[..., 0, 0], A[..., 0, 1], A[..., 0, 3] = ct, -st, a
        A[..., 1, 0], A[..., 1, 1], A[..., 1, 2], A[..., 1, 3] = st * ca, ct * ca, -sa, -sa * d
        A[..., 2, 0], A[..., 2, 1], A[..., 2, 2], A[..., 2, 3] = st * sa, ct * sa, ca, ca * d
        A[..., 3, 3] = 1.0
        T = T @ A
    T_flange = np.eye(4)
    T_flange[2, 3] = FR3_FLANGE_D_M
    return T @ T_flange @ (mount or InstrumentMount()).T_flange_tool()


class Fr3Kinematics:
    """Pinocchio model + data with the tool frame's pose and 6x7 Jacobian (LOCAL_WORLD_ALIGNED)."""

    def __init__(self, mount: InstrumentMount | None = None) -> None:
        self.mount = mount or InstrumentMount()
        self.model = build_fr3_model(self.mount)
        self.data = self.model.createData()
        self.tool_id = self.model.getFrameId("tool")
        self.q_min_rad = self.model.lowerPositionLimit.copy()
        self.q_max_rad = self.model.upperPositionLimit.copy()
        self.dq_max_radps = self.model.velocityLimit.copy()

    def tool_pose(self, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q (7,) -> (R_base_tool (3, 3), p_tip_base_m (3,))."""
        pin.framesForwardKinematics(self.model, self.data, q_rad)
        M = self.data.oMf[self.tool_id]
        return M.rotation.copy(), M.translation.copy()

    def pose_and_jacobian(self, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q (7,) -> (R_base_tool, p_tip_base_m, J (6, 7) = [v_tip; w] in base axes)."""
        J = pin.computeFrameJacobian(self.model, self.data, q_rad, self.tool_id, pin.LOCAL_WORLD_ALIGNED)
        M = pin.updateFramePlacement(self.model, self.data, self.tool_id)
        return M.rotation, M.translation, J

    def solve_ik(
        self,
        R_target: np.ndarray,
        p_target_m: np.ndarray,
        q_seed_rad: np.ndarray,
        iters: int = 500,
        tol: float = 1e-10,
    ) -> np.ndarray:
        """Damped Newton IK for the tool pose, started at the seed; raises if it does not converge.

        The seed is held in the Jacobian's null space, so the solution keeps its elbow and posture.
        """
        q = np.asarray(q_seed_rad, dtype=float).copy()
        q_seed = q.copy()
        for it in range(iters):
            R, p, J = self.pose_and_jacobian(q)
            err = np.concatenate([p_target_m - p, pin.log3(R_target @ R.T)])
            if np.linalg.norm(err) < tol:
                if np.all(q >= self.q_min_rad) and np.all(q <= self.q_max_rad):
                    return q
                break
            JJt = J @ J.T + 1e-6 * np.eye(6)
            J_pinv = J.T @ np.linalg.inv(JJt)
            dq = J_pinv @ err
            if it < iters // 2:  # posture first, then a pure Newton polish to full precision
                dq += (np.eye(N_JOINTS) - J_pinv @ J) @ (0.1 * (q_seed - q))
            q = np.clip(q + dq, self.q_min_rad, self.q_max_rad)
        raise ValueError(f"IK did not converge within joint limits from seed {q_seed_rad}")
