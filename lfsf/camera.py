"""Depth, 3-D points and 3-D scene flow from an estimate, for a calibrated camera.

The estimate is in the light field's own units: δ in pixels per view step, the flow in
pixels. With the camera of the centre view known (MODEL.md §7: focal length f in pixels,
baseline b between neighbouring views, disparity offset δ0 of the focus plane), a point
of disparity δ lies at depth

    Z = f·b / (δ + δ0),

and the point seen at pixel p = (x, y) at t1 is X(p, δ1), at t2 X(p + (u, v), δ2), where

    X(p, δ) = ((x − c_x)·Z / f, (y − c_y)·Z / f, Z)

in the centre camera's frame (x right, y down, z forward; the unit of b). The 3-D scene
flow is X(p + (u, v), δ2) − X(p, δ1). A camera that moves between the captures gives
the t2 points in its t2 frame.

>>> cam = Camera(focal=160.0, baseline=0.15, offset=4.0)      # doctest: +SKIP
>>> points1, points2 = sf.points(cam)                          # doctest: +SKIP
>>> scene_flow = points2 - points1                             # doctest: +SKIP
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from lfsf._errors import shown_number


#: The widest or tallest views a camera may have, in pixels.
MAX_SIZE = 1 << 20


def _finite(name: str, value) -> float:
    """A real number as a float, or a ValueError naming the setting."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"Camera: {name} must be a real number, got {value!r}")
    try:
        number = float(value)
    except OverflowError:   # (a whole number beyond a float's range)
        number = math.inf
    if not math.isfinite(number):
        raise ValueError(f"Camera: {name} must be finite, got {shown_number(value)}")
    return number


def _one_number(value, key: str) -> float:
    """A ground truth's ``key``, one real number (a 0-d array, or one of one element as
    ``np.savez(focal=[f])`` writes), as a float; else a ValueError naming it."""
    a = np.asarray(value)
    if a.size != 1 or a.dtype.kind not in "iuf":
        raise ValueError(f"'{key}' must be one number, got " + (f"{a.size} values, shape {a.shape}" if a.size != 1
                                                                 else f"dtype {a.dtype}"))
    return float(a.reshape(()))


@dataclass(frozen=True)
class Camera:
    """The pinhole camera of the centre view, to turn δ into depth and points (MODEL.md §7).

    Parameters
    ----------
    focal : float
        f, the focal length in pixels of the views (positive).
    baseline : float
        b, the distance between neighbouring views (positive); depths and points come out
        in its unit.
    offset : float
        δ0 in px per view step: δ + δ0 = f·b / Z. A camera whose views are aligned at
        infinity (a plain camera array) has δ0 = 0; one focused at distance Z_f, where
        δ = 0 (a plenoptic camera, a rig with shifted sensors), has δ0 = f·b / Z_f.
    principal : (c_x, c_y) or None
        The principal point in pixels (x right, y down, pixel centres at whole numbers);
        None: the views' centre, ((W − 1)/2, (H − 1)/2).
    size : (W, H) or None
        The views' size the camera is for, where known (a ``gt.npz``, a
        ``parameters.cfg``): maps of another size are refused, and
        :meth:`downsampled` then knows the full views' centre.
    """

    focal: float
    baseline: float
    offset: float = 0.0
    principal: tuple[float, float] | None = None
    size: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        for name in ("focal", "baseline"):
            value = _finite(name, getattr(self, name))
            if value <= 0:
                raise ValueError(f"Camera: {name} must be positive, got {value:g}")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "offset", _finite("offset", self.offset))
        if self.principal is not None:
            try:
                cx, cy = self.principal
            except (TypeError, ValueError):
                raise ValueError(f"Camera: principal must be (c_x, c_y) or None, got {self.principal!r}") from None
            object.__setattr__(self, "principal", (_finite("principal c_x", cx), _finite("principal c_y", cy)))
        if self.size is not None:
            try:
                width, height = (int(v) for v in self.size)
                if (width, height) != tuple(self.size) or not 1 <= min(width, height) <= max(width, height) <= MAX_SIZE:
                    raise ValueError
            except (TypeError, ValueError, OverflowError):
                shown = (f"({', '.join(shown_number(v) if isinstance(v, int) else repr(v) for v in self.size)})"
                         if isinstance(self.size, (tuple, list)) and len(self.size) == 2 else repr(self.size))
                raise ValueError(f"Camera: size must be (W, H), two whole numbers 1…{MAX_SIZE}, or None, got "
                                 f"{shown}") from None
            object.__setattr__(self, "size", (width, height))

    def depth(self, disp: ArrayLike) -> np.ndarray:
        """Z = f·b / (δ + δ0) of a disparity map (float32); NaN where δ + δ0 ≤ 0 (a point
        at or beyond infinity, or behind the camera) or δ is not finite."""
        d = np.asarray(disp, dtype=np.float64) + self.offset
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(d > 0, self.focal * self.baseline / d, np.nan)
        return z.astype(np.float32)

    def disparity(self, depth: ArrayLike) -> np.ndarray:
        """δ = f·b / Z − δ0 of a depth map (float32), the inverse of :meth:`depth`."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return (self.focal * self.baseline / np.asarray(depth, dtype=np.float64) - self.offset).astype(np.float32)

    def points(self, disp: ArrayLike, u: ArrayLike | None = None, v: ArrayLike | None = None) -> np.ndarray:
        """The 3-D points X(p + (u, v), δ) (float32 (H, W, 3)) of a disparity map δ (H, W)
        indexed by pixel p; ``u``, ``v`` (H, W), where given, move each pixel first (the
        t2 points of an estimate: ``points(disp2, u, v)``). NaN where :meth:`depth` is."""
        disp = np.asarray(disp)
        if disp.ndim != 2:
            raise ValueError(f"Camera.points: the disparity must be a 2-D map, got shape {disp.shape}")
        height, width = disp.shape
        if self.size is not None and self.size != (width, height):
            raise ValueError(f"Camera.points: this camera is for views of {self.size[0]}×{self.size[1]} px, the "
                             f"map is {width}×{height} (for views shrunk K times: camera.downsampled(K))")
        cx, cy = self.principal if self.principal is not None else ((width - 1) / 2.0, (height - 1) / 2.0)
        y, x = np.mgrid[0:height, 0:width].astype(np.float64)
        for name, shift, axis in (("u", u, x), ("v", v, y)):
            if shift is not None:
                shift = np.asarray(shift, dtype=np.float64)
                if shift.shape != disp.shape:
                    raise ValueError(f"Camera.points: {name} is {shift.shape}, the disparity {disp.shape}")
                axis += shift
        z = self.depth(disp).astype(np.float64)
        return np.stack([(x - cx) * z / self.focal, (y - cy) * z / self.focal, z], axis=-1).astype(np.float32)

    def downsampled(self, factor: int) -> "Camera":
        """The camera of the views shrunk ``factor`` times, each pixel the mean of factor ×
        factor (``LightField.downsample``, ``lfsf run --downsample``): f and δ0 divided
        by the factor, the principal point moved onto the smaller pixels' grid (the full
        views' centre where it is None and the size is known; without the size, the
        smaller views' centre, which is the same only where the factor divides the full
        sides: the block means drop the rest). The depths and points of the smaller
        views' δ are then those of the full views'."""
        k = int(factor) if isinstance(factor, (int, float, np.integer, np.floating)) else 0
        if k != factor or k < 1:
            raise ValueError(f"Camera.downsampled: the factor must be a whole number ≥ 1, got {factor!r}")
        if self.size is not None and min(self.size) < k:
            raise ValueError(f"Camera.downsampled: views of {self.size[0]}×{self.size[1]} cannot be shrunk {k} times")
        principal = self.principal
        if principal is None and self.size is not None:
            principal = ((self.size[0] - 1) / 2.0, (self.size[1] - 1) / 2.0)
        if principal is not None:
            principal = tuple((c + 0.5) / k - 0.5 for c in principal)
        size = None if self.size is None else (self.size[0] // k, self.size[1] // k)
        return Camera(self.focal / k, self.baseline, self.offset / k, principal, size)

    def as_dict(self) -> dict:
        return {"focal": self.focal, "baseline": self.baseline, "offset": self.offset,
                "principal": None if self.principal is None else list(self.principal),
                "size": None if self.size is None else list(self.size)}

    @classmethod
    def from_truth(cls, gt: Mapping[str, Any]) -> "Camera":
        """The camera that ``lfsf synth`` rendered with, from its ground truth (a mapping
        with ``focal``, ``baseline`` and ``shift``, as :func:`lfsf.render_scene` returns
        and ``gt.npz`` holds): δ = f·b/Z − shift, so δ0 = shift; the size of its maps."""
        missing = [k for k in ("focal", "baseline", "shift") if k not in gt]
        if missing:
            raise ValueError(f"no camera in this ground truth: it lacks {', '.join(missing)} (a gt.npz of "
                             "'lfsf synth' holds focal, baseline and shift)")
        size = np.shape(gt["disp1"])[::-1] if "disp1" in gt and np.ndim(gt["disp1"]) == 2 else None
        return cls(*(_one_number(gt[key], key) for key in ("focal", "baseline", "shift")), size=size)

    @classmethod
    def from_hci(cls, parameters: dict) -> "Camera":
        """The camera of an HCI 4D benchmark scene from its ``parameters.cfg`` (as
        ``LightField.meta["parameters"]`` holds it, ``{section: {key: value}}``): f in
        pixels = ``focal_length_mm`` / ``sensor_size_mm`` × the larger of
        ``image_resolution_x_px`` and ``image_resolution_y_px``, b = ``baseline_mm``, and
        the views focused (δ = 0) at ``focus_distance_m``: δ0 = f·b / Z_f. Depths and
        points come out in millimetres; the size is the image resolution's."""
        # (the benchmark's sections; any others only where a key is in neither)
        flat = {}
        for name, section in sorted(parameters.items(), key=lambda item: item[0] in ("intrinsics", "extrinsics")):
            if isinstance(section, dict):
                flat.update(section)
        keys = ("focal_length_mm", "sensor_size_mm", "image_resolution_x_px", "image_resolution_y_px",
                "baseline_mm", "focus_distance_m")
        def positive(value) -> bool:
            """A positive number of a float's range (a 400-digit integer had been an OverflowError)."""
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                return False
            try:
                return math.isfinite(float(value)) and value > 0
            except OverflowError:
                return False

        wrong = [k for k in keys if not positive(flat.get(k))]
        if wrong:
            raise ValueError(f"no camera in these parameters: {', '.join(wrong)} missing, or not a positive number "
                             "of a float's range (an HCI 4D benchmark parameters.cfg gives them)")
        width, height = flat["image_resolution_x_px"], flat["image_resolution_y_px"]
        if width != int(width) or height != int(height):
            raise ValueError(f"no camera in these parameters: image_resolution_x_px and _y_px must be whole numbers, "
                             f"got {width} and {height}")
        focal = flat["focal_length_mm"] / flat["sensor_size_mm"] * max(width, height)
        baseline = float(flat["baseline_mm"])
        return cls(focal, baseline, focal * baseline / (1000.0 * flat["focus_distance_m"]),
                   size=(int(width), int(height)))

    @classmethod
    def from_file(cls, path: str | os.PathLike) -> "Camera":
        """The camera a file records: a ``gt.npz`` of ``lfsf synth`` (:meth:`from_truth`),
        or an HCI ``parameters.cfg`` (:meth:`from_hci`), or a folder holding either (the
        ``parameters.cfg`` first).

        Raises
        ------
        FileNotFoundError
            Where there is no such file, or the folder holds no ``parameters.cfg``.
        ValueError
            Naming the file, where it records no camera.
        """
        from lfsf._files import file_name

        path = file_name(path, "a camera's file or folder")
        if path.is_dir():  # (an HCI folder, or lfsf synth's, as lfsf eval takes a folder)
            found = [path / name for name in ("parameters.cfg", "gt.npz") if (path / name).is_file()]
            if not found:
                raise FileNotFoundError(f"{path}: no parameters.cfg or gt.npz in this folder (a camera is read from "
                                        "an HCI parameters.cfg or a gt.npz of 'lfsf synth')")
            path = found[0]
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no such file")
        try:
            if path.suffix.lower() == ".npz":
                from lfsf.io import _read_npz_arrays

                _, arrays = _read_npz_arrays(path, ("focal", "baseline", "shift", "disp1"))
                return cls.from_truth(arrays)
            if path.suffix.lower() == ".cfg":
                import warnings

                from lfsf.io import _read_hci_parameters

                with warnings.catch_warnings():
                    warnings.simplefilter("error")
                    parameters = _read_hci_parameters(path)
                return cls.from_hci(parameters)
        except (ValueError, OverflowError, Warning) as exc:  # (the reader's warning says 'ignored': not here)
            said = str(exc).removeprefix(f"{path}: ").removeprefix("ignored, ").removeprefix("Camera: ")
            raise ValueError(f"{path}: {said}") from None
        raise ValueError(f"{path}: a camera is read from a gt.npz of 'lfsf synth' or an HCI parameters.cfg, not a "
                         f"{path.suffix or 'file without a suffix'}")


def scene_flow_errors(estimate, gt, camera: Camera, border: int | None = None) -> dict[str, float]:
    """Errors of an estimate's 3-D points and scene flow against a ground truth's, both
    through ``camera`` (MODEL.md §7).

    ``estimate``: an :class:`lfsf.SceneFlow` or a mapping with ``disp1``, ``disp2``,
    ``u``, ``v``; ``gt``: the same maps of the truth (a ``gt.npz`` of ``lfsf synth``;
    for a result of ``lfsf run --downsample K``, shrunk alike, and ``camera`` the light
    fields', which the result's recorded K shrinks here),
    with optional bool ``valid`` and ``occluded``. Over the valid pixels where the true
    points are finite, without ``border`` px at each edge (None: 8, as :func:`lfsf.evaluate.evaluate`):

    * ``epe3d``: the mean end-point error of the 3-D scene flow, ‖(X2 − X1) − (X2* − X1*)‖,
      in the baseline's unit, and ``epe3d_median``;
    * ``epe3d_noc``: the same over the points seen at t2 as well (where ``gt`` has ``occluded``);
    * ``depth1_rel``: the mean relative error of the t1 depth, |Z1 − Z1*| / Z1*;
    * ``motion``: the true 3-D motions' mean length, ‖X2* − X1*‖, for scale;
    * ``pixels``.

    A point of the estimate at or beyond infinity (δ + δ0 ≤ 0) where the truth's is finite
    counts as an infinite error."""
    from lfsf.evaluate import SYNTH_BORDER, _mask

    if hasattr(estimate, "maps_camera"):  # (a result of lfsf run --downsample K: its maps' camera, its truth's too)
        camera = estimate.maps_camera(camera)
    maps = estimate.as_dict() if hasattr(estimate, "as_dict") else estimate
    missing = [k for k in ("disp1", "disp2", "u", "v") for m in (maps, gt) if k not in m]
    if missing:
        raise ValueError("scene_flow_errors: the estimate and the truth need disp1, disp2, u and v; missing "
                         + ", ".join(sorted(set(missing))))
    shape = np.shape(gt["disp1"])
    if any(np.shape(m[k]) != shape for m in (maps, gt) for k in ("disp1", "disp2", "u", "v")):
        raise ValueError(f"scene_flow_errors: the maps must all be {shape[1]}×{shape[0]}, as the truth's δ1")
    est1, est2 = camera.points(maps["disp1"]), camera.points(maps["disp2"], maps["u"], maps["v"])
    true1, true2 = camera.points(gt["disp1"]), camera.points(gt["disp2"], gt["u"], gt["v"])
    finite = np.isfinite(true1).all(-1) & np.isfinite(true2).all(-1)
    scored = _mask(shape, gt.get("valid"), SYNTH_BORDER if border is None else border, finite)
    error = np.linalg.norm((est2 - est1) - (true2 - true1), axis=-1)
    error = np.where(np.isfinite(error), error, np.inf)
    depth = np.abs(est1[..., 2] - true1[..., 2]) / true1[..., 2]
    depth = np.where(np.isfinite(depth), depth, np.inf)
    out = {"epe3d": float(error[scored].mean()), "epe3d_median": float(np.median(error[scored])),
           "depth1_rel": float(depth[scored].mean()),
           "motion": float(np.linalg.norm((true2 - true1)[scored], axis=-1).mean()), "pixels": int(scored.sum())}
    if gt.get("occluded") is not None:
        seen = scored & ~np.asarray(gt["occluded"], dtype=bool)
        if seen.any():
            out["epe3d_noc"] = float(error[seen].mean())
    return out
