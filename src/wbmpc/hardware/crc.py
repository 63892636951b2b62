"""CRC of Unitree LowCmd_ / LowState_ messages, as the robot checks it: `unitree_go` (quadrupeds,
20 motor slots) and `unitree_hg` (humanoids such as G1, 35 motor slots).

The message is packed little-endian in the robot's C layout (formats from unitree_sdk2py's
`utils/crc.py`; unitree_hg LowCmd_ 1004 bytes, LowState_ 2092), cut into 32-bit words (the last word, the crc field itself, excluded) and run
through Unitree's `crc32_core`: CRC-32 with polynomial 0x04C11DB7, initial value 0xFFFFFFFF,
most significant bit first, no reflection, no final xor (CRC-32/MPEG-2 over the words' big-endian
bytes). zlib's CRC-32 is the reflected form of the same polynomial, so bit-reversing the input
bytes and the result turns it into this one at C speed.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

N_MOTOR_SLOTS = 20  # unitree_go
N_HG_MOTOR_SLOTS = 35  # unitree_hg
_LOW_CMD = struct.Struct("<4B4IH2x" + "B3x5f3I" * N_MOTOR_SLOTS + "4B" + "55Bx2I")  # 812 bytes
_LOW_STATE = struct.Struct("<4B4IH2x" + "13fb3x" + "B3x7fb3x3I" * N_MOTOR_SLOTS + "4BiH4b15H" + "8hI41B3xf2b2x2f4h2I")
# unitree_hg: mode_pr, mode_machine; per motor mode, q, dq, tau, kp, kd, reserve; reserve[4], crc
_HG_LOW_CMD = struct.Struct("<2B2x" + "B3x5fI" * N_HG_MOTOR_SLOTS + "5I")  # 1004 bytes
# version[2], mode_pr, mode_machine, tick; IMU (13 floats, int16 temperature); per motor mode, q, dq, ddq, tau_est,
# temperature[2], vol, sensor[2], motorstate, reserve[4]; wireless_remote[40], reserve[4], crc
_HG_LOW_STATE = struct.Struct("<2I2B2xI" + "13fh2x" + "B3x4f2hf7I" * N_HG_MOTOR_SLOTS + "40B5I")  # 2092 bytes
_BIT_REVERSE = bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))


def crc32_core(words: np.ndarray | list[int]) -> int:
    """Unitree's crc32_core over 32-bit words."""
    data = struct.pack(f">{len(words)}I", *(int(w) & 0xFFFFFFFF for w in words))
    reflected = zlib.crc32(data.translate(_BIT_REVERSE)) ^ 0xFFFFFFFF
    return int(f"{reflected:032b}"[::-1], 2)


def payload_words(packed: bytes) -> np.ndarray:
    """The 32-bit words a message's CRC covers: all of the packed message but its trailing CRC word."""
    return np.frombuffer(packed, dtype="<u4")[:-1]


def _crc_of(packed: bytes) -> int:
    words = payload_words(packed)
    reflected = zlib.crc32(words.astype(">u4").tobytes().translate(_BIT_REVERSE)) ^ 0xFFFFFFFF
    return int(f"{reflected:032b}"[::-1], 2)


def pack_low_cmd(cmd) -> bytes:
    values = [*cmd.head, cmd.level_flag, cmd.frame_reserve, *cmd.sn, *cmd.version, cmd.bandwidth]
    for m in cmd.motor_cmd:
        values += [m.mode, m.q, m.dq, m.tau, m.kp, m.kd, *m.reserve]
    values += [cmd.bms_cmd.off, *cmd.bms_cmd.reserve, *cmd.wireless_remote, *cmd.led, *cmd.fan, cmd.gpio,
               cmd.reserve, cmd.crc]
    return _LOW_CMD.pack(*values)


def pack_low_state(state) -> bytes:
    imu, bms = state.imu_state, state.bms_state
    values = [*state.head, state.level_flag, state.frame_reserve, *state.sn, *state.version, state.bandwidth,
              *imu.quaternion, *imu.gyroscope, *imu.accelerometer, *imu.rpy, imu.temperature]
    for m in state.motor_state:
        values += [m.mode, m.q, m.dq, m.ddq, m.tau_est, m.q_raw, m.dq_raw, m.ddq_raw, m.temperature, m.lost, *m.reserve]
    values += [bms.version_high, bms.version_low, bms.status, bms.soc, bms.current, bms.cycle, *bms.bq_ntc,
               *bms.mcu_ntc, *bms.cell_vol, *state.foot_force, *state.foot_force_est, state.tick,
               *state.wireless_remote, state.bit_flag, state.adc_reel, state.temperature_ntc1,
               state.temperature_ntc2, state.power_v, state.power_a, *state.fan_frequency, state.reserve, state.crc]
    return _LOW_STATE.pack(*values)


def pack_hg_low_cmd(cmd) -> bytes:
    values = [cmd.mode_pr, cmd.mode_machine]
    for m in cmd.motor_cmd:
        values += [m.mode, m.q, m.dq, m.tau, m.kp, m.kd, m.reserve]
    return _HG_LOW_CMD.pack(*values, *cmd.reserve, cmd.crc)


def pack_hg_low_state(state) -> bytes:
    imu = state.imu_state
    values = [*state.version, state.mode_pr, state.mode_machine, state.tick, *imu.quaternion, *imu.gyroscope,
              *imu.accelerometer, *imu.rpy, imu.temperature]
    for m in state.motor_state:
        values += [m.mode, m.q, m.dq, m.ddq, m.tau_est, *m.temperature, m.vol, *m.sensor, m.motorstate, *m.reserve]
    return _HG_LOW_STATE.pack(*values, *state.wireless_remote, *state.reserve, state.crc)


def is_hg(msg) -> bool:
    """A unitree_hg message (else unitree_go), from its IDL type name."""
    return msg.__idl_typename__.startswith("unitree_hg.")


def low_cmd_crc(cmd) -> int:
    """CRC of a LowCmd_ of either family."""
    return _crc_of(pack_hg_low_cmd(cmd) if is_hg(cmd) else pack_low_cmd(cmd))


def low_state_crc(state) -> int:
    """CRC of a LowState_ of either family."""
    return _crc_of(pack_hg_low_state(state) if is_hg(state) else pack_low_state(state))
