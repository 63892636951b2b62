"""The Z1 arm's UDP messages (Unitree z1_sdk <-> z1_controller), packed byte for byte as Unitree's C structs.

Layouts read from Unitree's `z1_sdk/include/unitree_arm_sdk/message/arm_common.h` (and the same file of
`z1_controller`), all `#pragma pack(1)`, little-endian (x86-64 / aarch64):

- `JointCmd` (20 B): float T (feed-forward torque, N m), W (velocity target, rad/s), Pos (position target,
  rad), K_P, K_W (position and velocity gains in the controller's units, below).
- `SendCmd` (147 B, SDK -> controller): uint8 head[2] = {0xFE, 0xFF}; ArmFSMState state (int32 enum);
  bool track; union ValueUnion (140 B: char name[10] | JointCmd jointCmd[7] | TrajCmd trajCmd (128 B)).
- `JointState` (22 B): float T, W, Acc, Pos; Motor_State state[2] (int8 temperature, uint8 error, uint8
  isConnected bit field: state in bits 6-7), two motors because joint 2 of the Z1 is a motor pair.
- `RecvState` (208 B, controller -> SDK): uint8 head[2]; ArmFSMState state; JointState jointState[7];
  Posture cartesianState (6 doubles: roll, pitch, yaw, x, y, z).

Seven joints: Z1 joints 1-6 then the gripper (index 6). The controller (`z1_controller`, State_LowCmd)
passes q = Pos, dq = W, tau = T and the gains to the motors, which apply tau + kp (q - q_m) + kd (dq - dq_m)
with kp = 25.6 K_P N m/rad and kd = 0.0128 K_W N m s/rad (the scales of z1_controller's simulation
interface, `sim/IOROS.cpp`; the SDK's default K_P 20-30 and K_W 2000 are 512-768 N m/rad and 25.6 N m s/rad).

Ports (z1_controller `main.cpp`, z1_sdk `CtrlComponents`): the controller listens on UDP 8071 of the arm's
computer and sends its state to the SDK on 8072 of 127.0.0.1 (the SDK runs on the same computer). The
controller accepts a SendCmd only when it is exactly 147 bytes with head {0xFE, 0xFF}; it leaves LOWCMD
for PASSIVE when the SDK goes silent, and only PASSIVE may switch to LOWCMD. The messages carry no CRC
(UDP's own checksum covers the datagram): wbmpc checks length, head, finite values and the FSM state.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

import numpy as np

from wbmpc.hardware.messages import MessageError

N_Z1_JOINTS = 7  # joints 1-6 + gripper
Z1_JOINT_NAMES = ("joint1", "joint2", "joint3", "joint4", "joint5", "joint6", "jointGripper")  # URDF names, Z1 order
SDK_HEAD = (0xFE, 0xFF)
CONTROLLER_PORT, SDK_PORT = 8071, 8072
CONTROLLER_IP = "127.0.0.1"
KP_UNIT_NM_PER_RAD = 25.6  # physical kp per K_P unit
KD_UNIT_NM_S_PER_RAD = 0.0128  # physical kd per K_W unit
# z1_sdk LowlevelCmd::setControlGain / setGripperGain: the SDK's LOWCMD gains (joints 1-6, gripper), K_P/K_W units
DEFAULT_KP_UNITS = (20.0, 30.0, 30.0, 20.0, 15.0, 10.0, 20.0)
DEFAULT_KD_UNITS = (2000.0,) * 7
# z1_controller config/savedArmStates.csv "startFlat": the folded pose the arm rests in (joints 1-6, rad)
Z1_REST_POSE_RAD = {"joint1": 0.0, "joint2": 0.0, "joint3": -0.005, "joint4": -0.074, "joint5": 0.0, "joint6": 0.0}


class ArmFsmState(enum.IntEnum):
    """`ArmFSMState` of arm_common.h (a C++ enum class: int32 on the wire)."""

    INVALID = 0
    PASSIVE = 1
    JOINTCTRL = 2
    CARTESIAN = 3
    MOVEJ = 4
    MOVEL = 5
    MOVEC = 6
    TRAJECTORY = 7
    TOSTATE = 8
    SAVESTATE = 9
    TEACH = 10
    TEACHREPEAT = 11
    CALIBRATION = 12
    SETTRAJ = 13
    BACKTOSTART = 14
    NEXT = 15
    LOWCMD = 16


JOINT_CMD = struct.Struct("<5f")  # T, W, Pos, K_P, K_W
TRAJ_CMD = struct.Struct("<i12d3di")  # trajType, posture[2] (6 d each), gripperPos, maxSpeed, stopTime, trajOrder
UNION_BYTES = max(10, N_Z1_JOINTS * JOINT_CMD.size, TRAJ_CMD.size)  # 140
SEND_CMD = struct.Struct(f"<2Bi?{N_Z1_JOINTS * 5}f{UNION_BYTES - N_Z1_JOINTS * JOINT_CMD.size}x")  # 147 B
JOINT_STATE = struct.Struct("<4f" + "bBB" * 2)  # T, W, Acc, Pos, Motor_State[2]
RECV_STATE = struct.Struct("<2Bi" + ("4f" + "bBB" * 2) * N_Z1_JOINTS + "6d")  # 208 B
assert (JOINT_CMD.size, TRAJ_CMD.size, UNION_BYTES, SEND_CMD.size) == (20, 128, 140, 147)
assert (JOINT_STATE.size, RECV_STATE.size) == (22, 208)


@dataclass
class Z1Command:
    """A SendCmd in physical units; arrays over the 7 Z1 joints (gains in N m/rad, N m s/rad)."""

    state: ArmFsmState
    q_rad: np.ndarray
    dq_rad_s: np.ndarray
    tau_nm: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    track: bool = False

    @staticmethod
    def switch(state: ArmFsmState) -> "Z1Command":
        """A command that only asks for an FSM state (the joint fields are ignored then)."""
        z = np.zeros(N_Z1_JOINTS)
        return Z1Command(state, z, z, z, z, z)


@dataclass
class Z1State:
    """A RecvState; arrays over the 7 Z1 joints."""

    state: ArmFsmState
    q_rad: np.ndarray
    dq_rad_s: np.ndarray
    ddq_rad_s2: np.ndarray
    tau_nm: np.ndarray
    temperature_c: np.ndarray  # of the first motor of each joint
    motor_error: np.ndarray  # Motor_State.error of the first motor
    posture: np.ndarray  # roll, pitch, yaw, x, y, z of the end effector


def encode_send_cmd(cmd: Z1Command) -> bytes:
    rows = np.stack([cmd.tau_nm, cmd.dq_rad_s, cmd.q_rad, np.asarray(cmd.kp) / KP_UNIT_NM_PER_RAD,
                     np.asarray(cmd.kd) / KD_UNIT_NM_S_PER_RAD], axis=1)  # JointCmd field order
    if rows.shape != (N_Z1_JOINTS, 5):
        raise ValueError(f"a Z1 command has {N_Z1_JOINTS} joints, got arrays of shape {rows.shape[:1]}")
    return SEND_CMD.pack(*SDK_HEAD, int(cmd.state), bool(cmd.track), *rows.ravel().tolist())


def decode_send_cmd(data: bytes) -> Z1Command:
    """Checked SendCmd (as z1_controller takes it) -> Z1Command; MessageError on a defect."""
    if len(data) != SEND_CMD.size:
        raise MessageError(f"Z1 command of {len(data)} bytes; a SendCmd has {SEND_CMD.size}")
    values = SEND_CMD.unpack(data)
    if tuple(values[:2]) != SDK_HEAD:
        raise MessageError(f"Z1 command head {values[:2]} is not {SDK_HEAD}")
    try:
        state = ArmFsmState(values[2])
    except ValueError:
        raise MessageError(f"Z1 command asks for FSM state {values[2]}, which does not exist") from None
    rows = np.array(values[4:], dtype=float).reshape(N_Z1_JOINTS, 5)
    if not np.all(np.isfinite(rows)) or np.any(rows[:, 3:] < 0):
        raise MessageError("Z1 command carries non-finite values or negative gains")
    return Z1Command(state, rows[:, 2], rows[:, 1], rows[:, 0], rows[:, 3] * KP_UNIT_NM_PER_RAD,
                     rows[:, 4] * KD_UNIT_NM_S_PER_RAD, bool(values[3]))


def encode_recv_state(state: Z1State) -> bytes:
    values: list = [*SDK_HEAD, int(state.state)]
    for j in range(N_Z1_JOINTS):
        motor = (int(state.temperature_c[j]), int(state.motor_error[j]), 0)
        values += [float(state.tau_nm[j]), float(state.dq_rad_s[j]), float(state.ddq_rad_s2[j]), float(state.q_rad[j]),
                   *motor, *motor]
    values += [float(x) for x in state.posture]
    return RECV_STATE.pack(*values)


def decode_recv_state(data: bytes) -> Z1State:
    """Checked RecvState -> Z1State; MessageError on a wrong length, unknown FSM state or non-finite value.
    The head is not checked: the SDK does not check it either."""
    if len(data) != RECV_STATE.size:
        raise MessageError(f"Z1 state of {len(data)} bytes; a RecvState has {RECV_STATE.size}")
    values = RECV_STATE.unpack(data)
    try:
        state = ArmFsmState(values[2])
    except ValueError:
        raise MessageError(f"Z1 state reports FSM state {values[2]}, which does not exist") from None
    joints = np.array(values[3:3 + 10 * N_Z1_JOINTS], dtype=float).reshape(N_Z1_JOINTS, 10)
    posture = np.array(values[3 + 10 * N_Z1_JOINTS:], dtype=float)
    if not (np.all(np.isfinite(joints[:, :4])) and np.all(np.isfinite(posture))):
        raise MessageError("Z1 state carries non-finite values")
    return Z1State(state, joints[:, 3], joints[:, 1], joints[:, 2], joints[:, 0], joints[:, 4], joints[:, 5].astype(int),
                   posture)
