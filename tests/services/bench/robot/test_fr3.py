"""FR3 model: the Pinocchio model built from the DH table against an independent numpy DH chain."""

from __future__ import annotations

import numpy as np
import pytest

from services.bench.robot.fr3 import (
    FR3_DQ_MAX_RADPS,
    FR3_Q_MAX_RAD,
    FR3_Q_MIN_RAD,
    Fr3Kinematics,
    InstrumentMount,
    build_fr3_model,
    fk_dh,
)


@pytest.mark.parametrize(
    "mount",
    [InstrumentMount(), InstrumentMount(0.30, (0.01, -0.02, 0.07), (5.0, -10.0, 45.0))],
)
def test_pinocchio_fk_matches_dh_over_random_configurations(mount: InstrumentMount) -> None:
    kin = Fr3Kinematics(mount)
    rng = np.random.default_rng(1234)
    q = rng.uniform(FR3_Q_MIN_RAD, FR3_Q_MAX_RAD, size=(1000, 7))
    T_dh = fk_dh(q, mount)
    for i in range(len(q)):
        R, p = kin.tool_pose(q[i])
        np.testing.assert_allclose(p, T_dh[i, :3, 3], atol=1e-9, rtol=0)
        np.testing.assert_allclose(R, T_dh[i, :3, :3], atol=1e-9, rtol=0)


def test_limits_come_from_the_table() -> None:
    model = build_fr3_model()
    assert model.nq == 7 and model.nv == 7
    np.testing.assert_array_equal(model.lowerPositionLimit, FR3_Q_MIN_RAD)
    np.testing.assert_array_equal(model.upperPositionLimit, FR3_Q_MAX_RAD)
    np.testing.assert_array_equal(model.velocityLimit, FR3_DQ_MAX_RADPS)
    assert model.existFrame("tool") and model.existFrame("flange")


def test_tool_frame_sits_at_the_tip_with_z_along_the_shaft() -> None:
    mount = InstrumentMount(shaft_length_m=0.34, p_flange_handle_m=(0.0, 0.0, 0.05))
    kin = Fr3Kinematics(mount)
    q = np.array([0.1, -0.4, 0.2, -2.3, 0.1, 2.2, 0.3])
    kin.tool_pose(q)
    flange = kin.data.oMf[kin.model.getFrameId("flange")]
    R, p = kin.tool_pose(q)
    np.testing.assert_allclose(np.linalg.norm(p - flange.translation), 0.39, atol=1e-12)
    # Straight instrument: the shaft axis continues the flange z axis, distally.
    np.testing.assert_allclose(R[:, 2], flange.rotation[:, 2], atol=1e-12)
    np.testing.assert_allclose((p - flange.translation) / 0.39, R[:, 2], atol=1e-12)


def test_jacobian_matches_finite_differences() -> None:
    kin = Fr3Kinematics()
    q = np.array([0.2, -0.5, -0.1, -2.4, 0.3, 2.5, -0.4])
    R, p, J = kin.pose_and_jacobian(q)
    R, p = R.copy(), p.copy()
    J = J.copy()
    h = 1e-7
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        R2, p2 = kin.tool_pose(q + dq)
        np.testing.assert_allclose((p2 - p) / h, J[:3, j], atol=1e-6)
        W = (R2 @ R.T - np.eye(3)) / h
        np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], J[3:, j], atol=1e-6)


def test_ik_reaches_the_pose_and_rejects_bad_input() -> None:
    kin = Fr3Kinematics()
    q_true = np.array([0.1, -0.45, -0.05, -2.5, 0.05, 2.6, 0.2])
    R, p = kin.tool_pose(q_true)
    q = kin.solve_ik(R, p, q_true + 0.1)
    R2, p2 = kin.tool_pose(q)
    np.testing.assert_allclose(p2, p, atol=1e-9)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    with pytest.raises(ValueError, match="IK"):
        kin.solve_ik(R, p + np.array([2.0, 0.0, 0.0]), q_true)
    with pytest.raises(ValueError, match="q_rad"):
        fk_dh(np.zeros(6))
    with pytest.raises(ValueError, match="shaft_length_m"):
        InstrumentMount(shaft_length_m=2.0)
