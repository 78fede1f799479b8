"""OpenCV's pinhole camera ``(K, dist, rvec, tvec)`` to and from a :class:`~shinysim.rig.Camera`, exactly.

:func:`camera_from_opencv` reads a calibration as OpenCV writes it (the
camera matrix, the distortion ``(k1, k2, p1, p2[, k3])``, the image size and
the world-to-camera pose), :func:`camera_to_opencv` gives it back as an
:class:`OpenCVCamera`; the two are inverse to rounding, and the camera
projects as ``cv2.projectPoints`` does. Both models place pixel centres at
integer coordinates. How the normalisations differ: the :class:`Camera`
docstring, and ``docs/file-format.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import RigError
from .core import ASPECT_RANGE, Camera

__all__ = ["OpenCVCamera", "ROTATION_TOLERANCE", "camera_from_opencv", "camera_to_opencv", "matrix_to_rvec",
           "rvec_to_matrix"]

#: How far ``R^T R`` of a rotation matrix may be from the identity (a matrix from
#: ``cv2.Rodrigues`` is orthonormal to rounding, ~1e-15).
ROTATION_TOLERANCE = 1e-9

#: OpenCV's distortion vectors longer than five terms, by length.
_LONGER_MODELS = {8: "the rational model (k4, k5, k6)", 12: "thin-prism terms (s1..s4)",
                  14: "a tilted sensor (tauX, tauY)"}


def _array(value, shape, field, what):
    """``value`` as a finite float array of ``shape``, else RigError naming ``field``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        arr = None
    if arr is None or arr.size != math.prod(shape) or not np.all(np.isfinite(arr)):
        raise RigError(f"must be {what}, got {value!r}", field=field)
    return arr.reshape(shape)


def rvec_to_matrix(rvec: ArrayLike) -> np.ndarray:
    """The rotation matrix of a rotation vector (Rodrigues' formula, as ``cv2.Rodrigues``).

    Parameters
    ----------
    rvec : (..., 3) array_like, radians
        Rotation axis times angle (right-handed).

    Returns
    -------
    (..., 3, 3) ndarray
        ``R = I + sin(t)/t K + (1 - cos(t))/t^2 K^2`` with ``K`` the
        cross-product matrix of ``rvec`` and ``t = |rvec|``, written with
        ``sinc`` so that it is exact down to ``rvec = 0``.

    Examples
    --------
    >>> np.round(rvec_to_matrix([0.0, 0.0, np.pi / 2]), 12) + 0.0
    array([[ 0., -1.,  0.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    r = np.asarray(rvec, dtype=float)
    if r.shape[-1:] != (3,):
        raise RigError(f"must have 3 components on its last axis, got shape {r.shape}", field="rvec")
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    zero = np.zeros_like(x)
    K = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
    half_sinc = np.sinc(theta / (2 * np.pi))  # sin(t/2) / (t/2): (1 - cos t) / t^2 = half_sinc^2 / 2
    return np.eye(3) + np.sinc(theta / np.pi) * K + 0.5 * half_sinc * half_sinc * (K @ K)


def matrix_to_rvec(matrix: ArrayLike) -> np.ndarray:
    """The rotation vector of a rotation matrix (the inverse of :func:`rvec_to_matrix`).

    Through the unit quaternion (Shepperd's choice of its largest component),
    so that it is exact near 0 and near pi alike.

    Parameters
    ----------
    matrix : (..., 3, 3) array_like
        Proper rotations: ``R^T R = I`` within :data:`ROTATION_TOLERANCE`,
        determinant +1.

    Returns
    -------
    (..., 3) ndarray, radians
        Angle in [0, pi].
    """
    R = np.asarray(matrix, dtype=float)
    if R.shape[-2:] != (3, 3) or not np.all(np.isfinite(R)):
        raise RigError(f"must be finite (3, 3) rotation matrices, got shape {R.shape}", field="rotation")
    gram = np.swapaxes(R, -1, -2) @ R - np.eye(3)
    if np.any(np.abs(gram) > ROTATION_TOLERANCE) or np.any(np.linalg.det(R) < 0):
        raise RigError("is not a proper rotation (R^T R = I, det R = +1)", field="rotation")
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    d0, d1, d2 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    pick = np.argmax(np.stack([tr, d0, d1, d2], -1), axis=-1)
    q = np.empty((len(m), 4))  # (w, x, y, z)
    for case in range(4):
        s = pick == case
        a = m[s]
        if case == 0:
            w = 0.5 * np.sqrt(1.0 + tr[s])
            q[s] = np.stack([w, (a[:, 2, 1] - a[:, 1, 2]) / (4 * w), (a[:, 0, 2] - a[:, 2, 0]) / (4 * w),
                             (a[:, 1, 0] - a[:, 0, 1]) / (4 * w)], -1)
        elif case == 1:
            x = 0.5 * np.sqrt(1.0 + d0[s] - d1[s] - d2[s])
            q[s] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / (4 * x), x, (a[:, 0, 1] + a[:, 1, 0]) / (4 * x),
                             (a[:, 0, 2] + a[:, 2, 0]) / (4 * x)], -1)
        elif case == 2:
            y = 0.5 * np.sqrt(1.0 - d0[s] + d1[s] - d2[s])
            q[s] = np.stack([(a[:, 0, 2] - a[:, 2, 0]) / (4 * y), (a[:, 0, 1] + a[:, 1, 0]) / (4 * y), y,
                             (a[:, 1, 2] + a[:, 2, 1]) / (4 * y)], -1)
        else:
            z = 0.5 * np.sqrt(1.0 - d0[s] - d1[s] + d2[s])
            q[s] = np.stack([(a[:, 1, 0] - a[:, 0, 1]) / (4 * z), (a[:, 0, 2] + a[:, 2, 0]) / (4 * z),
                             (a[:, 1, 2] + a[:, 2, 1]) / (4 * z), z], -1)
    q = np.where(q[:, :1] < 0, -q, q)  # w >= 0: the angle in [0, pi]
    s = np.linalg.norm(q[:, 1:], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(s > 0, 2.0 * np.arctan2(s, q[:, 0]) / s, 2.0 / q[:, 0])
    return (q[:, 1:] * factor[:, None]).reshape(R.shape[:-1])


@dataclass(frozen=True, eq=False)
class OpenCVCamera:
    """A perspective camera as OpenCV writes it (see :func:`camera_to_opencv`).

    Parameters
    ----------
    matrix : (3, 3) ndarray
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, pixels.
    distortion : (5,) ndarray
        ``(k1, k2, p1, p2, k3)``, OpenCV's normalisation (by the focal length).
    image_size : (width, height)
        Pixels.
    rvec : (3,) ndarray, radians
        World-to-camera rotation: ``x_cam = R(rvec) x_world + tvec``.
    tvec_mm : (3,) ndarray, millimetres
    """

    matrix: np.ndarray
    distortion: np.ndarray
    image_size: tuple[int, int]
    rvec: np.ndarray
    tvec_mm: np.ndarray

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) ``R(rvec)``: its rows are the camera's x (right), y (down) and z (forward) in the world."""
        return rvec_to_matrix(self.rvec)


def camera_from_opencv(matrix: ArrayLike, distortion: ArrayLike, image_size: tuple[int, int],
                       rvec: ArrayLike | None = None, tvec_mm: ArrayLike | None = None, *,
                       distance_mm: float = 1000.0, name: str = "camera") -> Camera:
    """The :class:`~shinysim.rig.Camera` of an OpenCV calibration.

    Parameters
    ----------
    matrix : (3, 3) array_like
        The camera matrix ``K``. OpenCV reads only ``fx = K[0, 0]``,
        ``fy = K[1, 1]``, ``cx = K[0, 2]`` and ``cy = K[1, 2]``;
        ``K[1, 0]``, ``K[2, 0]``, ``K[2, 1]`` and the skew ``K[0, 1]`` must
        be 0. ``K[2, 2]`` is ignored, as ``cv2.projectPoints`` ignores it.
    distortion : (4,) or (5,) array_like
        ``(k1, k2, p1, p2[, k3])`` as OpenCV orders them (a (1, 5) array
        from ``cv2.calibrateCamera`` is fine). Longer vectors (the rational,
        thin-prism and tilted models) are refused.
    image_size : (width, height)
        Pixels, OpenCV's order.
    rvec, tvec_mm : (3,) array_like, optional
        OpenCV's world-to-camera pose ``x_cam = R(rvec) x_world + tvec``,
        radians and millimetres. Default: the identity (the camera frame
        is the world frame).
    distance_mm : float
        Where the camera's ``target`` is put on its optical axis; a gauge
        (the rays do not depend on it), but ``field_width`` is measured
        there.
    name : str

    Returns
    -------
    Camera
        Perspective, with ``position = -R^T tvec``, ``forward = R^T e_z``,
        ``right = R^T e_x``, ``up = -R^T e_y``, ``field_width = width
        distance_mm / fx``, ``principal_point = (cy, cx)``, ``aspect = fy /
        fx`` and the distortion in shinysim's normalisation (``t = width /
        (2 fx)``: ``k1 t^2``, ``k2 t^4``, ``p1 t``, ``p2 t``, ``k3 t^6``).

    Raises
    ------
    RigError
        Naming the bad argument (``matrix[0, 1]`` for a skew, ``distortion``
        for too many terms or a map that folds the image, ...).

    Examples
    --------
    >>> K = [[5492.06, 0, 812.5], [0, 5486.27, 617.5], [0, 0, 1]]
    >>> cam = camera_from_opencv(K, [-0.1442, 1.6097, 2.5e-5, -1.9e-3, 0.0], (1626, 1236))
    >>> round(cam.aspect, 6), cam.principal_point_px.tolist()
    (0.998946, [617.5, 812.5])
    >>> np.allclose(camera_to_opencv(cam).matrix, K, rtol=1e-14)
    True
    """
    K = _array(matrix, (3, 3), "matrix", "a (3, 3) matrix of finite numbers")
    for i, j in ((0, 1), (1, 0), (2, 0), (2, 1)):
        if K[i, j] != 0.0:
            what = "a skew, which shinysim does not model" if (i, j) == (0, 1) else "not 0"
            raise RigError(f"is {K[i, j]!r}: {what} (OpenCV's K is [[fx, 0, cx], [0, fy, cy], [0, 0, 1]])",
                           field=f"matrix[{i}, {j}]")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for (i, j), f in (((0, 0), fx), ((1, 1), fy)):
        if not f > 0:
            raise RigError(f"the focal length must be > 0 pixels, got {f!r}", field=f"matrix[{i}, {j}]")
    if not ASPECT_RANGE[0] < fy / fx < ASPECT_RANGE[1]:
        raise RigError(f"fy / fx = {fy / fx!r} is outside {ASPECT_RANGE}: a real sensor's pixels are within a few "
                       "per cent of square", field="matrix[1, 1]")
    try:
        k = np.asarray(distortion, dtype=float).ravel()
    except (TypeError, ValueError, OverflowError):
        k = np.full(1, np.nan)
    if k.size in _LONGER_MODELS:
        raise RigError(f"has {k.size} terms: {_LONGER_MODELS[k.size]} is not modelled; give (k1, k2, p1, p2[, k3])",
                       field="distortion")
    if k.size not in (4, 5) or not np.all(np.isfinite(k)):
        raise RigError(f"must be 4 or 5 finite numbers (k1, k2, p1, p2[, k3]), got {distortion!r}",
                       field="distortion")
    k1, k2, p1, p2, k3 = (*k, 0.0) if k.size == 4 else k
    size = tuple(image_size) if isinstance(image_size, (tuple, list, np.ndarray)) else ()
    if len(size) != 2 or not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n >= 1
                                 for n in size):
        raise RigError(f"must be (width, height), two integers >= 1, got {image_size!r}", field="image_size")
    width, height = int(size[0]), int(size[1])
    R = rvec_to_matrix(np.zeros(3) if rvec is None else _array(rvec, (3,), "rvec", "3 finite numbers (radians)"))
    t = np.zeros(3) if tvec_mm is None else _array(tvec_mm, (3,), "tvec_mm", "3 finite numbers (millimetres)")
    d = distance_mm
    if isinstance(d, bool) or not isinstance(d, (int, float, np.integer, np.floating)) or not (
            math.isfinite(d) and d > 0):
        raise RigError(f"must be a finite distance > 0 mm, got {d!r}", field="distance_mm")
    position = -R.T @ t + 0.0  # + 0.0: no negative zeros in the JSON
    forward, down = R[2], R[1]
    s = width / (2.0 * fx)  # shinysim's normalised radius 1 is s in OpenCV's
    try:
        return Camera("perspective", width, height, position, position + float(d) * forward, -down + 0.0,
                      width * float(d) / fx, name, principal_point=(cy, cx),
                      distortion=(k1 * s**2, k2 * s**4, p1 * s, p2 * s, k3 * s**6), aspect=fy / fx)
    except RigError as exc:
        if exc.field == "distortion":
            raise RigError(f"{tuple(k.tolist())} (OpenCV's normalisation) folds the image; in shinysim's "
                           f"normalisation: {exc.problem}", field="distortion") from None
        raise


def camera_to_opencv(camera: Camera) -> OpenCVCamera:
    """OpenCV's model of a perspective :class:`~shinysim.rig.Camera`; the inverse of :func:`camera_from_opencv`.

    Parameters
    ----------
    camera : Camera
        Perspective (an orthographic camera has no pinhole model).

    Returns
    -------
    OpenCVCamera
        ``fx = width distance / field_width``, ``fy = fx aspect``, ``(cx, cy)``
        the principal point, the distortion in OpenCV's normalisation, and
        the world-to-camera pose (``R`` with rows ``right``, ``down``,
        ``forward``; ``tvec = -R position``).
    """
    if not isinstance(camera, Camera):
        raise RigError(f"must be a Camera, got {type(camera).__name__}", field="camera")
    if camera.projection != "perspective":
        raise RigError(f"is {camera.projection!r}: OpenCV's pinhole model needs a perspective camera",
                       field="projection")
    fx = camera.width * camera.distance / camera.field_width
    pr, pc = camera.principal_point_px
    K = np.array([[fx, 0.0, pc], [0.0, fx * camera.aspect, pr], [0.0, 0.0, 1.0]])
    s = camera.field_width / (2.0 * camera.distance)  # = width / (2 fx)
    k1, k2, p1, p2, k3 = camera.distortion
    dist = np.array([k1 / s**2, k2 / s**4, p1 / s, p2 / s, k3 / s**6])
    R = np.stack([camera.right, camera.down, camera.forward])
    arrays = [K, dist, matrix_to_rvec(R), -R @ camera.position]
    for a in arrays:
        a.setflags(write=False)
    return OpenCVCamera(arrays[0], arrays[1], (camera.width, camera.height), arrays[2], arrays[3])
