"""Small CasADi (SX) helpers for 3D rotations, SO(3)/SE(3) exponential and logarithm.

Singular points (zero angle) use Taylor expansions selected with `if_else`, whose unused branch
is masked for values and derivatives, so no NaN leaks into the NLP at delta-q = 0.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

SMALL_ANGLE_SQ = 1e-6  # below this theta^2 the Taylor branches are exact to ~1e-18


def const(array) -> ca.SX:
    """Numeric array -> SX constant with round-off zeros/ones snapped, so SX simplifies 0*x and 1*x."""
    a = np.array(array, dtype=float)
    a[np.abs(a) < 1e-14] = 0.0
    a[np.abs(a - 1.0) < 1e-14] = 1.0
    a[np.abs(a + 1.0) < 1e-14] = -1.0
    return ca.SX(ca.DM(a))


def is_identity(matrix: np.ndarray) -> bool:
    return bool(np.allclose(matrix, np.eye(3), atol=1e-14, rtol=0))


def cross(a: ca.SX, b: ca.SX) -> ca.SX:
    """Cross product of 3-vectors, built elementwise so constant zeros vanish from the graph."""
    return ca.vertcat(
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )


def skew(w: ca.SX) -> ca.SX:
    return ca.vertcat(
        ca.horzcat(0, -w[2], w[1]),
        ca.horzcat(w[2], 0, -w[0]),
        ca.horzcat(-w[1], w[0], 0),
    )


def axis_rotation(axis: np.ndarray, cos_q, sin_q) -> ca.SX:
    """Rotation matrix about a unit axis; aligned axes give the sparse textbook matrices."""
    axis = np.asarray(axis, dtype=float)
    c, s = cos_q, sin_q
    if np.allclose(axis, [1, 0, 0]):
        return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))
    if np.allclose(axis, [0, 1, 0]):
        return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))
    if np.allclose(axis, [0, 0, 1]):
        return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))
    k = const(axis)
    kx = skew(k)
    return ca.SX.eye(3) + s * kx + (1 - c) * ca.mtimes(kx, kx)


def quat_to_rotation(quat_xyzw: ca.SX) -> ca.SX:
    """Rotation matrix of a unit quaternion stored (x, y, z, w) as in pinocchio's q."""
    x, y, z, w = quat_xyzw[0], quat_xyzw[1], quat_xyzw[2], quat_xyzw[3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return ca.vertcat(
        ca.horzcat(1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)),
        ca.horzcat(2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)),
        ca.horzcat(2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)),
    )


def quat_multiply(q1: ca.SX, q2: ca.SX) -> ca.SX:
    """Hamilton product of quaternions stored (x, y, z, w)."""
    v1, w1 = q1[:3], q1[3]
    v2, w2 = q2[:3], q2[3]
    v = w1 * v2 + w2 * v1 + cross(v1, v2)
    return ca.vertcat(v, w1 * w2 - ca.dot(v1, v2))


def _exp_coefficients(theta_sq: ca.SX):
    """sin(t)/t, (1-cos t)/t^2, (t - sin t)/t^3 as functions of t^2, safe at t = 0."""
    ts = ca.fmax(theta_sq, SMALL_ANGLE_SQ)  # both branches stay finite, so do their derivatives
    t = ca.sqrt(ts)
    small = theta_sq < SMALL_ANGLE_SQ
    a = ca.if_else(small, 1 - theta_sq / 6 + theta_sq**2 / 120, ca.sin(t) / t)
    b = ca.if_else(small, 0.5 - theta_sq / 24 + theta_sq**2 / 720, (1 - ca.cos(t)) / ts)
    c = ca.if_else(small, 1.0 / 6 - theta_sq / 120 + theta_sq**2 / 5040, (t - ca.sin(t)) / (t * ts))
    return a, b, c


def exp_so3(w: ca.SX) -> ca.SX:
    """Rodrigues' formula R = exp([w]x)."""
    a, b, _ = _exp_coefficients(ca.dot(w, w))
    wx = skew(w)
    return ca.SX.eye(3) + a * wx + b * ca.mtimes(wx, wx)


def exp_se3(v_lin: ca.SX, w: ca.SX) -> tuple[ca.SX, ca.SX]:
    """SE(3) exponential of a twist (linear, angular): returns (R, p) with p = V(w) v_lin."""
    a, b, c = _exp_coefficients(ca.dot(w, w))
    wx = skew(w)
    wx2 = ca.mtimes(wx, wx)
    rotation = ca.SX.eye(3) + a * wx + b * wx2
    translation = v_lin + b * cross(w, v_lin) + c * cross(w, cross(w, v_lin))
    return rotation, translation


def quat_exp(w: ca.SX) -> ca.SX:
    """Unit quaternion (x, y, z, w) of the rotation exp([w]x)."""
    theta_sq = ca.dot(w, w)
    small = theta_sq < SMALL_ANGLE_SQ
    t = ca.sqrt(ca.fmax(theta_sq, SMALL_ANGLE_SQ))
    half_sinc = ca.if_else(small, 0.5 - theta_sq / 48 + theta_sq**2 / 3840, ca.sin(t / 2) / t)
    cos_half = ca.if_else(small, 1 - theta_sq / 8 + theta_sq**2 / 384, ca.cos(t / 2))
    return ca.vertcat(half_sinc * w, cos_half)


def quat_log(quat_xyzw: ca.SX) -> ca.SX:
    """Rotation vector w with exp([w]x) = R(quat); shortest rotation (|w| <= pi)."""
    sign = ca.if_else(quat_xyzw[3] < 0, -1, 1)
    v = sign * quat_xyzw[:3]
    w_scalar = sign * quat_xyzw[3]
    n_sq = ca.dot(v, v)
    n = ca.sqrt(ca.fmax(n_sq, 1e-20))
    small = n_sq < 1e-10
    # theta / n with theta = 2 atan2(n, w); near zero 2/w (1 - x^2/3 + x^4/5), x = n / w
    x_sq = n_sq / ca.fmax(w_scalar * w_scalar, 1e-6)
    ratio = ca.if_else(small, 2 / ca.fmax(w_scalar, 1e-3) * (1 - x_sq / 3 + x_sq**2 / 5), 2 * ca.atan2(n, w_scalar) / n)
    return ratio * v


def log_se3_translation(w: ca.SX, p: ca.SX) -> ca.SX:
    """Linear part of log6: V(w)^-1 p."""
    theta_sq = ca.dot(w, w)
    small = theta_sq < SMALL_ANGLE_SQ
    ts = ca.fmax(theta_sq, SMALL_ANGLE_SQ)
    t = ca.sqrt(ts)
    # coefficient of [w]x^2 in V^-1: (1 - t sin t / (2 (1 - cos t))) / t^2
    big_coef = (1 - t * ca.sin(t) / (2 * (1 - ca.cos(t)))) / ts
    coef = ca.if_else(small, 1.0 / 12 + theta_sq / 720 + theta_sq**2 / 30240, big_coef)
    return p - 0.5 * cross(w, p) + coef * cross(w, cross(w, p))
