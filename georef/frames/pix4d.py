"""Pix4D's yaw, pitch, roll and accuracies from the EO table, and how OpenDroneMap reads them per camera make.

Pix4D's definition (support article 202558969, "Yaw, Pitch, Roll and Omega, Phi, Kappa angles", read 2026): the
camera body has x towards the top of the image and z along the viewing direction; yaw, pitch, roll rotate local
north-east-down into it as ``C = Rz(yaw) Ry(pitch) Rx(roll)``; yaw 0 = top of the image north, **pitch 0 = nadir**,
pitch 90 = looking forward. georef's camera frame (``docs/conventions.md``: the body frame x forward, y right,
z down, turned by the boresight) is that frame, so the EO table's camera roll, pitch, yaw [deg] *are* Pix4D's
roll, pitch, yaw. The same angles go into the PIX4D image-geolocation CSV (``georef.io.exports.write_pix4d``) and
into the ``Camera:Yaw/Pitch/Roll`` XMP tags of image copies (``georef.io.image_tags``).

Accuracies are "the sigma of the normal distribution" per axis (Pix4D FAQ, article 360015702911): one horizontal
value is the per-axis sigma of the isotropic distribution with the same total variance, sqrt((s1^2 + s2^2) / 2),
not hypot(s1, s2) (sqrt 2 larger).

OpenDroneMap reads ``Camera:Yaw/Pitch/Roll`` with Pix4D's meaning but changes two of them by the camera's
``Make`` (OpenDroneMap/ODM 3.6.0, ``opendm/photo.py``, ``ODM_Photo.parse_exif_values``, commit 32cfaacf): it adds
90 deg to the pitch of ``DJI`` and ``Hasselblad`` images (DJI's gimbal pitch is -90 at nadir) and negates the
roll of ``senseFly`` images, whichever tag the angle came from. :func:`tag_angles_for_make` writes the angles
so that ODM's reading gives back Pix4D's angles for those makes too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

#: makes whose pitch OpenDroneMap 3.6 raises by 90 deg (``camera_make.lower() in ['dji', 'hasselblad']``)
ODM_PITCH_PLUS_90_MAKES = ("dji", "hasselblad")
#: makes whose roll OpenDroneMap 3.6 negates (``camera_make.lower() == 'sensefly'``)
ODM_ROLL_NEGATED_MAKES = ("sensefly",)
#: what OpenDroneMap adds to a DJI or Hasselblad pitch [deg]
ODM_DJI_PITCH_OFFSET_DEG = 90.0


@dataclass(frozen=True)
class Pix4dAngles:
    """Pix4D's yaw [0, 360), pitch, roll of the camera [deg] (module docstring)."""

    yaw: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray


def pix4d_angles(roll_deg: ArrayLike, pitch_deg: ArrayLike, yaw_deg: ArrayLike) -> Pix4dAngles:
    """Pix4D's angles of the camera from the EO table's camera roll, pitch, yaw [deg]: the same rotation, the same
    numbers (yaw wrapped to [0, 360))."""
    return Pix4dAngles(yaw=np.mod(np.asarray(yaw_deg, float), 360.0), pitch=np.asarray(pitch_deg, float),
                       roll=np.asarray(roll_deg, float))


def per_axis_sigma(sigma_1: ArrayLike, sigma_2: ArrayLike) -> np.ndarray:
    """One horizontal 1-sigma [m] from the sigmas of two perpendicular axes: sqrt((s1^2 + s2^2) / 2)."""
    return np.sqrt((np.asarray(sigma_1, float) ** 2 + np.asarray(sigma_2, float) ** 2) / 2.0)


def tag_angles_for_make(angles: Pix4dAngles, make: str) -> Pix4dAngles:
    """The angles to write into ``Camera:Yaw/Pitch/Roll`` of an image whose EXIF ``Make`` is ``make`` so that
    OpenDroneMap 3.6 reads Pix4D's ``angles`` back: pitch - 90 for DJI and Hasselblad (DJI's gimbal convention,
    -90 = nadir), -roll for senseFly, unchanged otherwise."""
    key = make.strip().lower()
    pitch = angles.pitch - ODM_DJI_PITCH_OFFSET_DEG if key in ODM_PITCH_PLUS_90_MAKES else angles.pitch
    roll = -angles.roll if key in ODM_ROLL_NEGATED_MAKES else angles.roll
    return Pix4dAngles(yaw=angles.yaw, pitch=pitch, roll=roll)
