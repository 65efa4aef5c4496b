"""Rigid camera poses and the rotation maps they need (SO(3) exp/log, quaternions)."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def hat(w: np.ndarray) -> np.ndarray:
    """float64[3, 3] skew-symmetric matrix with ``hat(w) @ v == cross(w, v)``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


@numba.njit(cache=True, nogil=True)
def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (float64[3], axis * angle in radians)."""
    theta = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    k = hat(w)
    if theta < 1e-8:
        return np.eye(3) + k + 0.5 * (k @ k)
    a = np.sin(theta) / theta
    b = (1.0 - np.cos(theta)) / (theta * theta)
    return np.eye(3) + a * k + b * (k @ k)


@numba.njit(cache=True, nogil=True)
def so3_log(r: np.ndarray) -> np.ndarray:
    """Rotation vector (float64[3]) of the rotation matrix ``r`` (inverse of so3_exp)."""
    cos = min(max((r[0, 0] + r[1, 1] + r[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    theta = np.arccos(cos)
    vee = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    if theta < 1e-8:
        return 0.5 * vee
    if np.pi - theta < 1e-6:
        # Near pi the antisymmetric part vanishes; take the axis from the symmetric part.
        m = (r + np.eye(3)) / 2.0
        i = np.argmax(np.array([m[0, 0], m[1, 1], m[2, 2]]))
        axis = m[i].copy()
        return theta * axis / np.sqrt(np.sum(axis * axis))
    return theta / (2.0 * np.sin(theta)) * vee


def quat_from_matrix(r: np.ndarray) -> np.ndarray:
    """float64[4] unit quaternion ``(qx, qy, qz, qw)`` with ``qw >= 0``."""
    m = r
    tr = np.trace(m)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion ``(qx, qy, qz, qw)`` (normalised first)."""
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


@dataclass(frozen=True, eq=False)
class Pose:
    """Camera-to-world transform: ``X_world = R_wc @ X_cam + t_wc``.

    ``t_wc`` is the optical centre in world coordinates (metres); the columns of ``R_wc``
    are the camera's x (right), y (down), z (forward) axes in the world frame.
    """

    r_wc: np.ndarray
    t_wc: np.ndarray

    @property
    def r_cw(self) -> np.ndarray:
        return self.r_wc.T

    @property
    def t_cw(self) -> np.ndarray:
        return -self.r_wc.T @ self.t_wc

    def matrix(self) -> np.ndarray:
        """float64[4, 4] homogeneous camera-to-world matrix."""
        m = np.eye(4)
        m[:3, :3] = self.r_wc
        m[:3, 3] = self.t_wc
        return m

    def to_tq(self) -> np.ndarray:
        """float64[7] ``tx, ty, tz, qx, qy, qz, qw`` (Event Camera Dataset order)."""
        return np.concatenate([self.t_wc, quat_from_matrix(self.r_wc)])


@dataclass(frozen=True, eq=False)
class Twist:
    """Camera velocity: linear ``v_w`` (m/s) and angular ``w_w`` (rad/s), world frame."""

    v_w: np.ndarray
    w_w: np.ndarray

    def in_camera(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """``(v_c, w_c)``: the same velocities expressed in the camera frame."""
        return pose.r_cw @ self.v_w, pose.r_cw @ self.w_w
