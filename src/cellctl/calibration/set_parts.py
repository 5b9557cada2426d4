"""The parts of a calibration set: each part's values (validated field by field) and its record.

A part carries its values, when and how it was made (method, software, the dataset it came
from), its quality figures and warnings, the ids of the parts it was computed with, and how long it
stays valid; ``status = "failed"`` keeps a failed part with its reason. The set itself and its
history: cellctl.calibration.calibration_set.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from cellctl.geometry.pose import check_pose


class CalibrationSetError(ValueError):
    """A calibration set file cannot be used; the message names each bad field."""


class StrictRecord(BaseModel):
    """Unknown fields are refused and records never change once read."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def _finite_matrix(v: Any, shape: tuple[int, ...], what: str) -> list[Any]:
    a = np.asarray(v, dtype=float)
    if a.shape != shape:
        raise ValueError(f"{what} must be a {' x '.join(map(str, shape))} array, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what} contains NaN or infinite values")
    return a.tolist()  # type: ignore[no-any-return]


def _pose(v: Any) -> list[list[float]]:
    m = _finite_matrix(v, (4, 4), "pose")
    check_pose(np.asarray(m), "pose", tol=1e-6)
    return m


class CameraValues(StrictRecord):
    K: list[list[float]]
    dist: list[float]
    image_size: tuple[int, int]

    @field_validator("K")
    @classmethod
    def _k(cls, v: Any) -> list[list[float]]:
        K = np.asarray(_finite_matrix(v, (3, 3), "K"))
        if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[1, 0]) + abs(K[2, 0]) + abs(K[2, 1]) > 0 or K[2, 2] != 1.0:
            raise ValueError("K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        return K.tolist()  # type: ignore[no-any-return]

    @field_validator("dist")
    @classmethod
    def _dist(cls, v: Any) -> list[float]:
        return _finite_matrix(v, (5,), "dist (k1, k2, p1, p2, k3)")

    @model_validator(mode="after")
    def _pp_inside(self) -> "CameraValues":
        w, h = self.image_size
        if w <= 0 or h <= 0:
            raise ValueError(f"image_size must be positive (width, height), got {self.image_size}")
        if not (0 <= self.K[0][2] < w and 0 <= self.K[1][2] < h):
            raise ValueError("the principal point (K[0][2], K[1][2]) lies outside the image")
        return self


class HandEyeValues(StrictRecord):
    T_H_C: list[list[float]]

    @field_validator("T_H_C")
    @classmethod
    def _pose_ok(cls, v: Any) -> list[list[float]]:
        return _pose(v)


class LaserValues(StrictRecord):
    r: list[float]
    l: list[float]  # noqa: E741

    @field_validator("r")
    @classmethod
    def _r(cls, v: Any) -> list[float]:
        return _finite_matrix(v, (3,), "r")

    @field_validator("l")
    @classmethod
    def _l(cls, v: Any) -> list[float]:
        a = np.asarray(_finite_matrix(v, (3,), "l"))
        if abs(np.linalg.norm(a) - 1.0) > 1e-6:
            raise ValueError(f"l must be a unit vector, its length is {np.linalg.norm(a):.9f}")
        return a.tolist()  # type: ignore[no-any-return]


class PixelMapValues(StrictRecord):
    affine: list[list[float]]
    scale_mm_per_px: float = Field(gt=0)

    @field_validator("affine")
    @classmethod
    def _affine(cls, v: Any) -> list[list[float]]:
        a = np.asarray(_finite_matrix(v, (2, 3), "affine"))
        if abs(np.linalg.det(a[:, :2])) < 1e-12:
            raise ValueError("affine: its 2x2 part is singular (it maps the image onto a line)")
        return a.tolist()  # type: ignore[no-any-return]


class WallRead(StrictRecord):
    """Where and how teaching read the wall: the cycle must read it the same way (the robot's errors cancel)."""

    mode: Literal["stop_and_go", "on_the_fly"]  # process.align.mode when taught
    spots_mm: list[tuple[float, float]] = Field(min_length=3)  # in T0: process.align.wall_spots_mm() when taught


class TaughtShot(StrictRecord):
    """The settings the taught shot stood on: T0, the template and the pixel map hold only with them; g_Pos_0 only
    for the opening's size (the glass is made to it)."""

    working_distance_mm: float  # process.working_distance_mm
    feature: Literal["corner", "arc"]  # what the shot measured
    corner_radius_mm: float  # the opening's ([layout.opening] or the recipe's)
    aim_mm: tuple[float, float]  # in T: the point on the camera's axis (vision.shot_aim_mm or its default)
    width_mm: float | None = None  # the opening's, as corner_radius_mm (None: taught before the size was recorded)
    height_mm: float | None = None


class TaughtStepValues(StrictRecord):
    """One step of a template's edge profile: place from the feature step (px, + into the opening), change (DN), share of the range."""

    offset_px: float
    change_dn: float
    fraction: float = Field(ge=0)


class TaughtEdgeValues(StrictRecord):
    """A template's profile across one straight edge: its steps, which is the feature, what it covered (px from the feature)."""

    steps: list[TaughtStepValues] = Field(min_length=1)
    feature: int = Field(ge=0)
    seen_px: tuple[float, float]

    @model_validator(mode="after")
    def _feature_in(self) -> "TaughtEdgeValues":
        if self.feature >= len(self.steps):
            raise ValueError(f"feature {self.feature} is not one of the {len(self.steps)} steps")
        return self


class TaughtProfileValues(StrictRecord):
    """The template's profiles (cellctl.vision.taught_profile), by edge, and the [vision.feature] rule they were picked with."""

    count_from: Literal["wall", "opening"]
    index: int = Field(ge=0)
    min_step_fraction: float = Field(gt=0, lt=1)
    edges: dict[Literal["top", "right"], TaughtEdgeValues]


class TeachingValues(StrictRecord):
    recipe: str | None = None  # the recipe taught (None: taught before recipes had their own teaching; the first)
    wall_read: WallRead | None = None  # None: taught before teachings recorded it (not checked)
    shot: TaughtShot | None = None  # None: taught before teachings recorded it (not checked)
    profile: TaughtProfileValues | None = None  # None: taught before profiles were recorded (the rule alone counts)
    T0: list[list[float]]
    C_Pos_0: list[list[float]]
    g_Pos_0: list[list[float]]
    u_d: float
    v_d: float
    theta_d: float
    top_angle_d: float | None  # None: that edge is not in view (an arc corner's right edge)
    right_angle_d: float | None

    @field_validator("T0", "C_Pos_0", "g_Pos_0")
    @classmethod
    def _pose_ok(cls, v: Any) -> list[list[float]]:
        return _pose(v)

    @field_validator("u_d", "v_d", "theta_d", "top_angle_d", "right_angle_d")
    @classmethod
    def _finite(cls, v: float | None) -> float | None:
        if v is not None and not np.isfinite(v):
            raise ValueError("must be a finite number (or null for an edge not in view)")
        return v


class DatasetRef(StrictRecord):
    """Where the data of a part lies and a fingerprint of it, for audits and recomputation."""

    kind: str
    path: str
    manifest_sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    summary: dict[str, Any] = {}


class WrittenBy(StrictRecord):
    """Who wrote a version of the set outside the service, and from what (``cellctl calibrate ... --dataset``)."""

    actor: str = Field(min_length=1)  # the OS account the command ran as
    source: str = Field(min_length=1)  # "cli:offline"
    host: str = ""
    dataset: str | None = None  # the dataset folder computed from
    dataset_manifest_sha256: str | None = Field(default=None, pattern=r"^[0-9a-f]{64}$")


class PartRecord(StrictRecord):
    """What every part records beside its values: id, status, when, how, from what, how good."""

    id: str = Field(min_length=1)
    status: Literal["ok", "failed"]
    calibrated_utc: datetime
    valid_days: float = Field(gt=0)
    method: str
    software: dict[str, str] = {}
    inputs: dict[str, str] = {}
    dataset: DatasetRef | None = None
    quality: dict[str, Any] = {}
    warnings: list[str] = []
    failure: str | None = None

    @field_validator("calibrated_utc")
    @classmethod
    def _aware(cls, v: datetime) -> datetime:
        if v.tzinfo is None:
            raise ValueError("needs a time zone (write it as UTC, e.g. 2025-01-31T12:00:00Z)")
        return v.astimezone(timezone.utc)

    @model_validator(mode="after")
    def _status(self) -> "PartRecord":
        values = getattr(self, "values", None)
        if self.status == "ok" and (values is None or self.failure is not None):
            raise ValueError("a part with status 'ok' needs values and no failure")
        if self.status == "failed" and not self.failure:
            raise ValueError("a part with status 'failed' needs the failure reason")
        return self


class CameraPart(PartRecord):
    values: CameraValues | None = None


class HandEyePart(PartRecord):
    values: HandEyeValues | None = None


class LaserPart(PartRecord):
    values: LaserValues | None = None


class PixelMapPart(PartRecord):
    values: PixelMapValues | None = None


class TeachingPart(PartRecord):
    values: TeachingValues | None = None


AnyPart = CameraPart | HandEyePart | LaserPart | PixelMapPart | TeachingPart
PART_MODELS: dict[str, type[PartRecord]] = {
    "camera": CameraPart,
    "hand_eye": HandEyePart,
    "laser": LaserPart,
    "pixel_map": PixelMapPart,
    "teaching": TeachingPart,
}


class RecipeParts(StrictRecord):
    """A recipe's own parts: its teaching and the nine-point map taken at its shooting pose."""

    pixel_map: PixelMapPart | None = None
    teaching: TeachingPart | None = None


class Parts(StrictRecord):
    camera: CameraPart | None = None
    hand_eye: HandEyePart | None = None
    laser: LaserPart | None = None
    pixel_map: PixelMapPart | None = None
    teaching: TeachingPart | None = None
