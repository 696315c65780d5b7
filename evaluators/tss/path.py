"""The camera path of ``evaluate.tss``: a VR head's small, smooth motion (Sec. 3.2: "viewport
movements in VR applications are typically small and smooth, as the camera is bound to the
user's head").

The base pose looks at the plane's centre from ``elevation_deg`` above it, ``distance_m``
away, at ``azimuth_deg``. The head then rotates (yaw about the base up axis, pitch about
its right axis, roll about its view axis) about a pivot ``pivot_m`` behind the eye, so that
a rotation moves the eye as a neck does, and translates along the base camera's axes. Each
of the six degrees of freedom is ``amplitude * sum_k w_k sin(2 pi f_k t + phi_k) / sum_k
w_k`` with ``w_k = 1/k``, ``t = frame / fps`` and seeded phases ``phi``: at most the
amplitude, smooth, and zero amplitudes give a static camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from evaluators.tss.params import PathSpec


@dataclass(frozen=True)
class CameraPath:
    """Per-frame pinhole cameras, float64.

    Attributes:
        eye: ``(F, 3)`` eye positions, world, metres.
        basis: ``(F, 3, 3)`` rows ``right, up, forward`` (unit, world).
        tan_half_fov: ``tan(fov_x / 2)``.
    """

    eye: np.ndarray
    basis: np.ndarray
    tan_half_fov: float

    @property
    def frames(self) -> int:
        return int(self.eye.shape[0])

    def motion(self) -> dict[str, float]:
        """Per-frame motion between consecutive frames: the eye's travel in millimetres and
        the view's rotation in degrees (mean and max; 0 for a single frame)."""
        if self.frames < 2:
            return {"translation_mm_mean": 0.0, "translation_mm_max": 0.0,
                    "rotation_deg_mean": 0.0, "rotation_deg_max": 0.0}  # fmt: skip
        step = np.linalg.norm(np.diff(self.eye, axis=0), axis=1) * 1e3
        rel = np.einsum("fij,fkj->fik", self.basis[1:], self.basis[:-1])
        cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        angle = np.degrees(np.arccos(cos))
        return {
            "translation_mm_mean": round(float(step.mean()), 4),
            "translation_mm_max": round(float(step.max()), 4),
            "rotation_deg_mean": round(float(angle.mean()), 4),
            "rotation_deg_max": round(float(angle.max()), 4),
        }

    def document(self, shading_frames: dict[str, list[int]]) -> dict[str, Any]:
        """``path.json``: the cameras and, per interval, the frames shaded."""
        return {
            "convention": "world z up; basis rows right, up, forward; pinhole, fov_x = "
            "2 atan(tan_half_fov); pixel (x, y) centre at ndc ((x + 0.5) / W * 2 - 1, "
            "1 - (y + 0.5) / H * 2), ray right * ndc_x * t + up * ndc_y * t * H / W + "
            "forward with t = tan_half_fov",
            "tan_half_fov": self.tan_half_fov,
            "eye": np.round(self.eye, 7).tolist(),
            "basis": np.round(self.basis, 7).tolist(),
            "motion": self.motion(),
            "shading_frames": shading_frames,
        }


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: the rotation by ``angle`` radians about the unit ``axis``."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def base_pose(spec: PathSpec) -> tuple[np.ndarray, np.ndarray]:
    """The base eye ``(3,)`` and basis ``(3, 3)`` (rows right, up, forward): looking at the
    origin from ``spec``'s elevation, azimuth and distance; right is horizontal."""
    el, az = math.radians(spec.elevation_deg), math.radians(spec.azimuth_deg)
    eye = spec.distance_m * np.array(
        [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]
    )
    forward = -eye / np.linalg.norm(eye)
    right = np.array([-math.sin(az), math.cos(az), 0.0])
    up = np.cross(right, forward)
    return eye, np.stack([right, up / np.linalg.norm(up), forward])


def camera_path(spec: PathSpec, frames: int, rng: np.random.Generator) -> CameraPath:
    """The seeded path of ``frames`` frames (phases drawn from ``rng``: 6 x K uniforms)."""
    freqs = np.asarray(spec.frequencies_hz, np.float64)
    weights = 1.0 / np.arange(1, len(freqs) + 1)
    phases = rng.uniform(0.0, 2.0 * math.pi, size=(6, len(freqs)))
    t = np.arange(frames, dtype=np.float64) / spec.fps
    waves = np.sin(2.0 * math.pi * freqs[None, None, :] * t[:, None, None] + phases[None])
    signal = (waves * weights).sum(axis=2) / weights.sum()  # (F, 6) in [-1, 1]
    eye0, basis0 = base_pose(spec)
    right0, up0, forward0 = basis0
    pivot = eye0 - spec.pivot_m * forward0
    rot = np.radians(spec.rotation_deg) * signal[:, :3]
    shift = spec.translation_m * signal[:, 3:] @ basis0  # along right, up, forward
    eyes, bases = np.empty((frames, 3)), np.empty((frames, 3, 3))
    for f in range(frames):
        yaw, pitch, roll = rot[f]
        r = _rotation(up0, yaw) @ _rotation(right0, pitch) @ _rotation(forward0, roll)
        eyes[f] = pivot + r @ (eye0 - pivot) + shift[f]
        bases[f] = (r @ basis0.T).T
    return CameraPath(eye=eyes, basis=bases, tan_half_fov=math.tan(math.radians(spec.fov_deg) / 2))
