"""The exported splat files' axes (:mod:`frng.apps.export`, :mod:`frng.apps.gltf_asset`): the asset's world is
right-handed with Z up; glTF and SPZ are right-handed with Y up and +Z to the front: (x, y, z) -> (x, z, -y)."""

from __future__ import annotations

import math

import numpy as np

Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # asset -> glTF / SPZ axes, (3, 3)
Y_UP_QUAT = np.array([math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0])  # the same rotation, (w, x, y, z)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a b of quaternions (..., 4) (w, x, y, z)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )


__all__ = ["Y_UP", "Y_UP_QUAT", "quat_multiply"]
