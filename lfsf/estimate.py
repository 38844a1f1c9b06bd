"""Scene flow from two light fields: sampling, structure–texture split, pyramid and
coarse-to-fine warping around :class:`lfsf.solver.LevelSolver` (MODEL.md §2–§7)."""

from __future__ import annotations

import contextvars
import functools
import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, NamedTuple, Union

import numpy as np

from lfsf import device as _device
from lfsf._errors import interrupts_kept, warn_at_caller
from lfsf._filters import box_mean
from lfsf._filters import gaussian_blur as _blur
from lfsf.gains import (GAIN_CHANGE, MAX_GAIN, MIN_VIEW_SIZE, fit_reduced_gains, gain_change, reduction_factor,
                        sampled_views)
from lfsf.io import (MAX_LENS_VIEWS, LightField, _a, _check_pair_brightest, _refuse_non_finite, centre_view, luma,
                     read_lightfield)
from lfsf.params import MAX_FLOW_RANGE, Params

if TYPE_CHECKING:
    from lfsf.camera import Camera


@dataclass(eq=False, repr=False)
class SceneFlow:
    """The estimate for the centre view at t1 (the conventions of ``help(lfsf)``, MODEL.md §1).

    Attributes
    ----------
    disp1, disp2 : float32 (H, W)
        δ1, and δ2 = the t2 disparity of the point seen at p at t1 (px per view step).
    u, v : float32 (H, W)
        Flow to the centre view at t2 (px).
    params : Params
        The settings used.
    radius : float
        The sampling radius R used (limited to the view grid).
    device : str
        The Warp device that estimated it (``"cpu"``, ``"cuda:0"``).
    timings : dict
        Seconds per stage.
    exposure : (g, b) or None
        Where t2's views were matched to t1's exposure (``Params.match_exposure``): they
        were replaced by g·L2 + b (intensities after any stretch to [0, 1]), or by a tone
        curve whose best line this is (the progress says which); None where no change of
        exposure was matched. A change over part of the view matched by a smooth field
        (:func:`_local_light`) is not in it; the progress tells of it.
    occluded : bool (H, W) or None
        The points of the t1 centre view that the estimate does not see in the centre view
        at t2: hidden there by a nearer point, or carried out of the image by their flow
        (:meth:`lfsf.solver.LevelSolver.occluded_at`). No view at t2 observes their δ2 and
        flow: where the estimator's own test found them hidden, these come from the
        motion of their own surface (``Params.hidden_fill_sigma``), else from the
        regulariser and the neighbours. (The fill also takes points hidden by less than
        this mask's margin, ``lfsf.solver.FILL_MARGIN``, which the mask leaves out.)
        None for flow only (no depth to tell which point is nearer).
    inputs : dict or None
        What a saved result records of its inputs (:meth:`load`; ``lfsf run
        --downsample K`` records ``downsample`` K and ``views``, the light fields' size
        (W, H) before shrinking; ``lfsf run`` and ``lfsf batch`` its light fields' paths,
        sizes and times, :func:`lfsf.batch.input_record`); None for a fresh estimate.
    made_with : dict or None
        The versions that made it (:func:`made_with`: lfsf, Python, NumPy, Warp); None
        for a result saved before they were recorded.

    ``==`` is identity: compare two results' maps with ``np.array_equal`` (``as_dict()``).
    """

    disp1: np.ndarray
    disp2: np.ndarray
    u: np.ndarray
    v: np.ndarray
    params: Params
    radius: float
    device: str
    timings: dict = field(default_factory=dict)
    exposure: tuple[float, float] | None = None
    occluded: np.ndarray | None = None
    inputs: dict | None = None
    made_with: dict | None = None

    def __post_init__(self) -> None:
        # the maps as the files promise them (float32 H×W, one shape), whoever made this
        maps = {}
        for name in ("disp1", "disp2", "u", "v"):
            try:
                maps[name] = np.asarray(getattr(self, name), dtype=np.float32)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"SceneFlow: {name} must be a 2-D map of real numbers ({exc})") from None
            if maps[name].ndim != 2 or maps[name].size == 0:
                raise ValueError(f"SceneFlow: {name} must be a non-empty 2-D map, got shape {maps[name].shape}")
            if maps[name].shape != maps["disp1"].shape:
                raise ValueError(f"SceneFlow: {name} is {maps[name].shape}, disp1 {maps['disp1'].shape}: the maps "
                                 "must have one shape")
            setattr(self, name, maps[name])
        if self.occluded is not None:
            occluded = np.asarray(self.occluded)
            if occluded.dtype != bool or occluded.shape != maps["disp1"].shape:
                raise ValueError(f"SceneFlow: occluded must be a bool map of the maps' shape {maps['disp1'].shape}, "
                                 f"got {occluded.dtype} {occluded.shape}")
            self.occluded = occluded
        if not isinstance(self.params, Params):
            raise ValueError(f"SceneFlow: params must be an lfsf.Params (the settings used), got "
                             f"{type(self.params).__name__}")

    # eq=False: a field-wise == of arrays raised "truth value of an array is ambiguous";
    # compare the maps with np.array_equal (or as_dict()) instead. repr: not four arrays.
    def __repr__(self) -> str:
        height, width = self.disp1.shape
        return f"SceneFlow({width}×{height}, R={self.radius:g}, device={self.device!r})"

    def _repr_png_(self) -> bytes:
        """The maps as a picture, which IPython and Jupyter show for a result at a cell's
        end: δ1, δ2 and the flow with their keys (:func:`lfsf.viz.maps_figure`), under a
        title of its size, sampling radius and device."""
        from lfsf import viz
        from lfsf.io import encode_png

        height, width = self.disp1.shape
        # ("x", not the repr's "×", which the pictures' font lacks)
        title = f"SceneFlow {width}x{height}, R={self.radius:g}, {self.device}"
        figure = viz.maps_figure(self.disp1, self.disp2, self.u, self.v, title=title,
                                 disparities=not self.params.flow_only)
        return encode_png(figure, source="SceneFlow")

    def as_dict(self) -> dict[str, np.ndarray]:
        """The four maps δ1, δ2, u, v by name (``disp1``, ``disp2``, ``u``, ``v``), as
        :func:`lfsf.evaluate.evaluate` and ``np.savez`` take them; ``occluded``, where
        there is one, is not among them (``evaluate(sf, gt)`` scores it too)."""
        return {"disp1": self.disp1, "disp2": self.disp2, "u": self.u, "v": self.v}

    def points(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        """The 3-D points of the t1 centre view's pixels at t1 and at t2, X(p, δ1) and
        X(p + (u, v), δ2), float32 (H, W, 3) each, in the centre camera's frame (x right,
        y down, z forward, the unit of the camera's baseline; NaN where δ + δ0 ≤ 0);
        their difference is the 3-D scene flow (MODEL.md §7). ``camera``: an
        :class:`lfsf.camera.Camera` of the light fields given to the estimate. A result
        of ``lfsf run --downsample K`` records K and the light fields' size
        (``inputs``): the camera is shrunk alike here (:meth:`Camera.downsampled`), and
        a camera without a size takes the recorded one.

        >>> points1, points2 = sf.points(lfsf.Camera(focal=640, baseline=0.0375, offset=4))  # doctest: +SKIP
        """
        from lfsf.camera import Camera

        if not isinstance(camera, Camera):
            raise ValueError(f"SceneFlow.points: camera must be an lfsf.Camera, got {type(camera).__name__}")
        if self.params.flow_only:
            raise ValueError("SceneFlow.points: a flow-only result (one circle) has no disparities to take depths "
                             "from; estimate with a light-field preset (paper, fast)")
        camera = self.maps_camera(camera)
        return camera.points(self.disp1), camera.points(self.disp2, self.u, self.v)

    def maps_camera(self, camera: Camera) -> Camera:
        """The camera of this result's maps, from the camera of the light fields given to
        the estimate: itself, or for a result of ``lfsf run --downsample K`` (``inputs``)
        shrunk K times, with the light fields' recorded size where the camera has none
        (so that the principal point stays the full views' centre)."""
        from dataclasses import replace

        from lfsf.evaluate import downsample_of

        k = downsample_of(self.inputs)
        if k == 1:
            return camera
        views = self.inputs.get("views")
        try:
            if camera.size is None and isinstance(views, list | tuple) and len(views) == 2 and all(
                    isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in views):
                camera = replace(camera, size=(int(views[0]), int(views[1])))
            return camera.downsampled(k)
        except ValueError as exc:   # (a result's own record that does not fit its camera)
            raise ValueError(f"{str(exc).removeprefix('Camera.downsampled: ')}; from what this result records of its "
                             f"light fields (their size, and --downsample {k})") from None

    @classmethod
    def load(cls, path: str | os.PathLike) -> "SceneFlow":
        """The result that :meth:`save` (or ``lfsf run``) wrote, from its folder or its
        ``sceneflow.npz``: the maps, ``occluded``, and the settings, sampling radius,
        device, timings and exposure it records. (:func:`lfsf.evaluate.load_estimate`
        reads the maps alone, from the other files too.)

        Raises
        ------
        FileNotFoundError
            Where there is no such file or folder, or the folder has no ``sceneflow.npz``.
        ValueError
            Naming the file, where it is not a result of :meth:`save`.
        """
        import json

        from lfsf import io
        from lfsf._files import file_name

        path = file_name(path, "a result's file or folder")
        file = path / "sceneflow.npz" if path.is_dir() else path
        if not file.is_file():
            raise FileNotFoundError(f"{file}: no such file (SceneFlow.load reads the sceneflow.npz that "
                                    "`lfsf run` and SceneFlow.save write)")
        keys, arrays = io._read_npz_arrays(file, ("disp1", "disp2", "u", "v", "occluded", "params"))
        missing = [k for k in ("disp1", "disp2", "u", "v", "params") if k not in arrays]
        if missing:
            raise ValueError(f"{file}: not a result of `lfsf run` or SceneFlow.save: no {', '.join(missing)} "
                             f"(keys: {', '.join(keys)})")
        try:
            meta = json.loads(str(arrays["params"]))
            params = Params.recorded(meta["params"])
            radius, device = float(meta["radius_used"]), str(meta["device"])
            timings, exposure = dict(meta.get("timings") or {}), meta.get("exposure")
            exposure = None if exposure is None else (float(exposure[0]), float(exposure[1]))
        except (KeyError, TypeError, ValueError, IndexError, OverflowError, RecursionError) as exc:
            raise ValueError(f"{file}: its recorded settings do not read as this version's ({exc})") from None
        occluded = arrays.get("occluded")
        try:
            inputs = meta.get("inputs") if isinstance(meta.get("inputs"), dict) else None
            made = meta.get("made_with")
            made = {str(k): str(v) for k, v in made.items()} if isinstance(made, dict) else None
            return cls(arrays["disp1"], arrays["disp2"], arrays["u"], arrays["v"], params, radius, device,
                       timings, exposure, None if occluded is None else np.asarray(occluded), inputs, made)
        except ValueError as exc:
            raise ValueError(f"{file}: {exc}") from None

    def save(self, out: str | os.PathLike, centre1: np.ndarray | None = None, centre2: np.ndarray | None = None,
             gt: Mapping[str, np.ndarray] | str | os.PathLike | None = None, title: str | None = None,
             border: int | None = None, inputs: dict | None = None) -> list[Path]:
        """Write ``disp1.pfm``, ``disp2.pfm``, ``flow.flo``, ``sceneflow.npz`` and the
        pictures ``disp1.png``, ``disp2.png``, ``flow.png`` (and ``overview.png`` when the
        centre views ``centre1`` and ``centre2``, at t1 and t2, are given) into ``out``, as
        one set: all are written into a temporary folder inside ``out`` first and moved
        into place only when every one is complete, so a failure or an interrupt leaves
        none of them (and no mix with an earlier run's). ``gt``, ``title`` and ``border``
        (that its error means leave out, as :func:`lfsf.evaluate.evaluate`'s) go to the
        overview (:func:`lfsf.viz.overview_figure`): ``gt`` or ``title`` without the centre
        views is an error. ``inputs``: what to record in ``sceneflow.npz`` of the inputs
        (``lfsf batch``'s :func:`lfsf.batch.input_record`; None: this result's own
        ``inputs``).
        :meth:`load` reads the result back.
        A flow-only result's (one circle) δ1 and δ2 pictures are plain grey
        (:data:`lfsf.viz.NOT_ESTIMATED_GREY`), and said to be not estimated in the overview.
        ``gt`` is a mapping of maps (:func:`lfsf.viz.ground_truth_maps`) or the path of a
        ``gt.npz`` or a PFM (:func:`lfsf.evaluate.load_ground_truth`), checked before the
        folder is made; the folders made for the result are removed again if writing
        fails. ``border`` left out (None) is what ``lfsf eval`` would leave out: the
        border of ``gt``'s kind of file (8 px for a ``gt.npz``, the HCI benchmark's 15 for
        a PFM), or 8 for a mapping (:data:`lfsf.evaluate.SYNTH_BORDER`, as
        :func:`lfsf.evaluate.evaluate`)."""
        from lfsf import viz
        from lfsf._files import output_folder
        from lfsf.batch import RESULT_FILES

        self.__post_init__()  # (maps changed since: a result that load would refuse is not written)
        if (centre1 is None) != (centre2 is None) or (centre1 is None and (gt is not None or title is not None)):
            raise ValueError("SceneFlow.save: overview.png needs both centre views (centre1, centre2); "
                             "gt and title go into it")
        gt_path = None
        if isinstance(gt, (str, os.PathLike)):  # (a gt.npz or a PFM, as lfsf run --gt takes it)
            from lfsf.evaluate import load_ground_truth

            gt_path = gt
            gt, kind_border = load_ground_truth(gt)
            border = kind_border if border is None else border
        if border is None:
            from lfsf.evaluate import SYNTH_BORDER

            border = SYNTH_BORDER if gt is not None else 0
        try:
            viz.ground_truth_maps(gt, self.disp1.shape)  # (checked before a folder is made)
        except ValueError as exc:
            if gt_path is None:
                raise
            raise ValueError(f"{os.fspath(gt_path)}: {exc}") from None
        from lfsf._files import folders_to_make, remove_made_folders

        made = folders_to_make(out)  # (the folders to make)
        out = output_folder(out)
        names = list(RESULT_FILES)
        if centre1 is not None and centre2 is not None:
            names.append("overview.png")
        try:
            return self._save_files(out, names, centre1, centre2, gt, title, border, inputs)
        except BaseException:
            remove_made_folders(made)  # (the folders made for this result, left empty by its failure)
            raise

    def _save_files(self, out: Path, names: list[str], centre1, centre2, gt, title, border, inputs) -> list[Path]:
        """:meth:`save`'s files, into the folder ``out`` that it checked."""
        import json

        from lfsf import io, viz
        from lfsf._files import file_set, stale_picture

        # an earlier result's overview goes with the rest of it (it had stayed, showing that
        # result beside this one's files)
        # (only where an earlier result is: an overview.png of the user's own stays)
        stale = () if "overview.png" in names else stale_picture(out, "overview.png", "sceneflow.npz")
        with file_set(out, names, stale) as tmp:
            for name in ("disp1", "disp2"):
                io.write_pfm(tmp / f"{name}.pfm", getattr(self, name))
            io.write_flo(tmp / "flow.flo", np.stack([self.u, self.v], -1))
            from lfsf import __version__

            # (the version that wrote it: settings added later read as their defaults, or as
            # what that version did, Params.recorded)
            meta = {"params": self.params.as_dict(), "radius_used": self.radius, "device": self.device,
                    "timings": self.timings, "exposure": self.exposure, "lfsf_version": __version__}
            if inputs is None:  # (what a loaded result recorded stays with it)
                inputs = self.inputs
            if inputs is not None:
                meta["inputs"] = inputs
            if self.made_with is not None:
                meta["made_with"] = self.made_with
            extra = {} if self.occluded is None else {"occluded": self.occluded}
            with open(tmp / "sceneflow.npz", "wb") as f:
                np.savez_compressed(f, **self.as_dict(), **extra, params=np.str_(json.dumps(meta)))
            # a flow-only run's δ1 and δ2 are zeros, not estimates: drawn as a plain grey
            # (each picture says in its PNG text what its colours mean: no scale is drawn in it)
            estimated = not self.params.flow_only
            lo, hi = _colour_range(self.disp1, self.disp2)
            for name, what in (("disp1", "disparity at t1"), ("disp2", "disparity at t2 of the t1 points")):
                if estimated:
                    picture = viz.disparity_to_color(getattr(self, name), lo, hi)
                    comment = (f"{name} ({what}) in px per view step: {lo:.4g} (dark purple) to {hi:.4g} "
                               "(yellow), values beyond in their colours; black: not finite")
                else:
                    picture = np.full(self.disp1.shape + (3,), viz.NOT_ESTIMATED_GREY, np.uint8)
                    comment = f"{name}: not estimated (a flow-only run, one circle)"
                viz.save_png(tmp / f"{name}.png", picture, text={"Comment": comment})
            viz.save_png(tmp / "flow.png", viz.flow_to_color(self.u, self.v),
                         text={"Comment": f"flow (u, v) of the t1 centre view in px, Middlebury colour wheel: "
                                          f"full colour at |(u,v)| = {viz.flow_scale(self.u, self.v):.4g} px"})
            if centre1 is not None and centre2 is not None:
                viz.overview_figure(centre1, centre2, self.disp1, self.disp2, self.u, self.v, gt=gt,
                                    path=tmp / "overview.png", title=title, occluded=self.occluded,
                                    disparities=estimated, border=border)
        return [out / name for name in names]


def _colour_range(*maps) -> tuple[float, float]:
    """The colour scale of disparity pictures: the 1st to 99th percentile over the maps'
    finite values (0 to 1 where there are none)."""
    values = np.concatenate([m[np.isfinite(m)] for m in maps])
    if values.size == 0:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(values, [1, 99]))
    return lo, max(hi, lo + 1e-3)


ProgressFn = Callable[[str], None]


class Warned(str):
    """A warning of the estimator about its input (float views far outside [0, 1], views
    laid out otherwise), given to the progress callable instead of
    :mod:`warnings` while :data:`WARNINGS_TO_PROGRESS` is set: ``lfsf batch`` reports it
    with the pair (its workers' threads share the warnings module's state, and no one
    reads their stderr)."""

    __slots__ = ()


#: Set (per thread and task, a :class:`contextvars.ContextVar`) to have the estimator's
#: warnings given to its progress callable as :class:`Warned` lines, not raised through
#: :mod:`warnings`.
WARNINGS_TO_PROGRESS: contextvars.ContextVar[bool] = contextvars.ContextVar("lfsf_warnings_to_progress",
                                                                            default=False)


def _warn(message: str, say) -> None:
    """``message`` as a :class:`Warned` line to ``say`` (:data:`WARNINGS_TO_PROGRESS`), or
    as an :class:`lfsf.LfsfWarning` at the line that called into lfsf
    (:func:`lfsf._errors.warn_at_caller`)."""
    if WARNINGS_TO_PROGRESS.get():
        say(Warned(message))
    else:
        warn_at_caller(message)


class Note(str):
    """A line of the progress that reports a decision about the input rather than how far
    the run has come: t2 matched to another exposure, or such a match refused; the views'
    gains matched; the view z-buffers off. A plain ``str`` to any progress callable; the
    command line prints these in logs too, where it leaves the progress out."""

    __slots__ = ()


#: The flow search runs on the finest level where its range is at most this many pixels
#: and which is at most FLOW_SEARCH_WIDTH pixels wide. Its 3×3 windows need texture of
#: the scene's scale, not the image's: at 640×480, searching the 160×120 level instead of
#: the 320×240 one took the `flow` preset's EPE from 0.190 / 0.090 / 0.322 / 0.211 to
#: 0.167 / 0.087 / 0.288 / 0.162 (paper / slanted / large_motion / weak_texture) and the
#: joint flow EPE from 0.076 / 0.033 / 0.129 / 0.110 to 0.074 / 0.031 / 0.134 / 0.117;
#: at 320×240 and 160×120 a level coarser than the range rule's lost large_motion's fast
#: objects (its flow-only EPE 0.409 → 0.496 at 320×240), and at 160×120 searching at full
#: resolution (finer than the range rule's 80 px) was worse too (flow preset EPE 0.211 /
#: 0.134 / 1.269 / 0.143 → 0.273 / 0.189 / 1.136 / 0.168). A measured rule, not a law.
FLOW_SEARCH_HALF = 12
FLOW_SEARCH_WIDTH = 160
#: … or which is scaled by at most this much: the width alone sent every image wider than
#: 642 px to ⅛ of its size, 81 px for 648 px. Flow EPE (`paper` preset) with the search
#: at ¼ against ⅛: 648×486 `large_motion` / `random-6` / `paper` 0.028 / 0.048 / 0.044
#: against 0.036 / 0.064 / 0.048 (`random-2` 0.050 against 0.048); 760×570 0.029 / 0.036
#: / 0.043 against 0.031 / 0.052 / 0.046; 960×720 0.034 / 0.041 / 0.050 against 0.035 /
#: 0.045 / 0.051. Below 643 px the rule picks what it did: at 360×270 and 400×300 the ¼
#: level (90, 100 px) beat the ½ one (180, 200 px) on 8 of 13 scenes (one tie).
FLOW_SEARCH_SCALE = 0.25
#: The flow search's largest half-width on its level: where the pyramid cannot bring the
#: range down to this (``max_levels``), (2·64 + 1)² shifts per pixel would already take
#: minutes at 640×480.
MAX_FLOW_SEARCH_HALF = 64
#: The flow search's match is ambiguous, and not fused (:func:`_fuse_flow`), in regions
#: (most of the FLOW_AMBIGUITY_AREA² pixels around) where its windowed cost is at least
#: this fraction of the least cost among the shifts at least FLOW_AMBIGUITY_DISTANCE
#: steps away along either axis, or where that runner-up's cost is below
#: FLOW_AMBIGUITY_FLOOR times the standard deviation of the search's t1 image (another
#: place matches almost exactly): a periodic texture, stripes (any shift along them
#: matches), a flat region. There the first shift in scan order had won, and fused it
#: replaced the right flow. Flow EPE, `paper` preset, 160×120 / 320×240: a checkerboard
#: (8-px squares) moving (3, 2) px 0.181 / 1.28 → 0.004 / 0.003; diagonal stripes (12 px)
#: 1.58 / 1.49 → 0.005 / 0.013; a textureless plane over half the image 5.74 / 8.40 →
#: 0.53 / 0.77 (OpenCV: 0.050 / 0.020, 0.064 / 0.032, 0.89 / 0.82). Pixel by pixel the
#: ratio's near-ties are common on the 3×3 windows of ordinary textures too (1–4 % of
#: the pixels where the search was right, on the 80×60 level at 160×120), and leaving
#: those out lost fast objects (`random-8` 0.168–0.226 → 0.291–0.357 over perturbed
#: runs). As regions they change 6 of the 68 built-in and `random-0…63` scenes at
#: 160×120 (a few pixels each; EPE 1.002× paired), 1 of 12 at 320×240 and 1 of
#: `random-64…95`; the floor changes none of them (on `paper`, `random-8` and
#: `weak_texture` the runner-up's cost is above 0.1 of the standard deviation at 95 % of
#: the pixels).
FLOW_AMBIGUITY = 0.95
FLOW_AMBIGUITY_DISTANCE = 3
FLOW_AMBIGUITY_AREA = 5
FLOW_AMBIGUITY_FLOOR = 0.02
#: Nor is any match fused in a region where the search's matches are noise: where the
#: texture is finer than the search's level resolves (gravel, grass, a fine random
#: texture), the level's downsampling aliases it, a true shift that falls between two of
#: its pixels matches no whole-pixel shift, and each 3×3 window's best shift is some
#: other one, won by chance. Such matches agree with none of their neighbours. A match
#: is incoherent where fewer than FLOW_COHERENCE_SHARE of the other pixels within
#: FLOW_COHERENCE_RADIUS have a match within 1 px of it (:func:`_coherent`), and nothing
#: is fused where more than FLOW_INCOHERENT_REGION of the FLOW_INCOHERENT_AREA² pixels
#: around are incoherent. There the matches had replaced a right flow of the
#: coarse-to-fine warping: a whole-image shift of skimage's `gravel` by (1, 1), (3, 3),
#: (5, 5) and (7, 2) px at 160×120, flow only with `paper`'s settings, had a flow EPE of
#: 0.17, 0.53, 1.40 and 0.21 px, now 0.001–0.005 (the search off: 0.001); `grass`
#: 0.006–0.083 → 0.001–0.002; white noise blurred by σ = 1 px 0.007–1.50 → 0.001–0.013
#: (``python scripts/fine_textures.py``). A periodic texture (`brick`) stays wrong either
#: way, its whole-period shifts being coherent (0.45–6.7 px against 0.55–4.8), and at
#: 96×72 `grass` moved by (5, 5) lost (0.16 → 1.8 px) where the other shifts gained. On the solid-
#: textured scenes the matches of moving objects are often scattered too, and right
#: (taking out the incoherent ones alone, or regions of 9² px more than 0.6 incoherent,
#: lost their flow: `random-12` EPE 0.021 → 0.12, 1.2× over 24 scenes); the region of
#: 25² px more than 0.85 incoherent leaves them as they were (`random-0…39` and the
#: built-in scenes at 160×120 and 320×240: no pixel in such a region but 4 of
#: `random-30`'s 80×60), and with photographs on the objects 18 of 20 at 160×120
#: (`random-24` a little better; `random-34`, at 2.8 px already, δ1 / δ2 / EPE 1.20 /
#: 1.17 / 1.05×) and the built-in four at 320×240 within chance (0.99 / 1.06 / 0.99).
FLOW_COHERENCE_SHARE = 0.3
FLOW_COHERENCE_RADIUS = 2
FLOW_INCOHERENT_AREA = 25
FLOW_INCOHERENT_REGION = 0.85

#: A warning where the flow search finds no clear match (ambiguous or incoherent) for more
#: than this share of the pixels and the flow estimated leaves t2 unlike t1 by more than
#: FLOW_UNMATCHED_RESIDUAL (:func:`_match_residual`). Shares measured at 96×72, `fast`:
#: 0–2 % on the built-in scenes and `random-3`, also with everything moved 20 px (within
#: the ±24 px searched); 84–100 % moved 30 or 40 px, and 97 % for two unrelated noise
#: images, where the estimate had come back without a word (EPE 26–33); 31 % on HCI
#: antinous and 1.4 % on the Lytro scene given as both times (flat regions); 84–100 % also
#: on noisy weak textures (σ = 0.03), whose flow matches as well as their noise allows:
#: the residual tells them apart (:func:`_match_residual`: 3.75–6.5 moved 30 or 40 px,
#: with noise or without; 0.8 on those; about 0 on a texture finer than the search's level,
#: which the search cannot match and the warping does).
FLOW_UNMATCHED_SHARE = 0.7
FLOW_UNMATCHED_RESIDUAL = 2.0


def _match_residual(centres: np.ndarray, u: np.ndarray, v: np.ndarray) -> float:
    """How unlike t1 the flow (u, v) leaves t2: the median of |I1(p) − I2(p + (u, v))| over
    the pixels whose p + (u, v) lies inside, over the median difference of neighbouring
    pixels of I1, which noise and fine texture set (the centre views ``centres``, (2, h,
    w)). About 1 or less where the flow matches, noisy or flat views too (0.8 on
    `weak_texture` and `random-2` with noise of σ = 0.03); 4–6.5 on textured scenes moved
    farther than the search reaches, with noise or without. (Over I1's spread instead,
    noisy flat views had read 0.6–1.2, as the scenes moved too far.)"""
    c1, c2 = centres[0].astype(np.float64), centres[1].astype(np.float64)
    h, w = c1.shape
    yy, xx = np.mgrid[0:h, 0:w]
    px, py = xx + u, yy + v
    inside = (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
    if not inside.any():
        return 0.0
    left = float(np.median(np.abs(c1 - _bilinear(c2, px, py))[inside]))
    floor = float(np.median(np.abs(np.diff(c1, axis=1)))) if w > 1 else 0.0
    # (0 where most neighbours of I1 are equal, a dark centre view: nothing to tell a match
    # by, and the dark view is told of on its own)
    return left / floor if floor > 0 else 0.0


def _coherent(flow: np.ndarray, share: float = FLOW_COHERENCE_SHARE, tolerance: float = 1.0) -> np.ndarray:
    """Pixels whose flow (h, w, 2) at least ``share`` of the other pixels within
    FLOW_COHERENCE_RADIUS (those inside the image) share to within ``tolerance`` px
    (bool (h, w))."""
    h, w = flow.shape[:2]
    r = FLOW_COHERENCE_RADIUS
    pad = np.pad(flow.astype(np.float32), ((r, r), (r, r), (0, 0)), constant_values=np.nan)
    agree = np.zeros((h, w), np.int32)
    inside = np.zeros((h, w), np.int32)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dy or dx:
                other = pad[r + dy:r + dy + h, r + dx:r + dx + w]
                with np.errstate(invalid="ignore"):
                    agree += np.hypot(other[..., 0] - flow[..., 0], other[..., 1] - flow[..., 1]) <= tolerance
                inside += ~np.isnan(other[..., 0])
    return agree >= share * inside


def _incoherent_regions(flow: np.ndarray) -> np.ndarray:
    """Where the flow search's matches (h, w, 2) are noise (bool (h, w)): more than
    FLOW_INCOHERENT_REGION of the FLOW_INCOHERENT_AREA² pixels around are incoherent
    (:func:`_coherent`)."""
    incoherent = (~_coherent(flow)).astype(np.float32)
    return box_mean(incoherent, FLOW_INCOHERENT_AREA) > FLOW_INCOHERENT_REGION


#: Searched matches from t1 to t2 and back agree to within this many pixels (of the
#: search's level) where both see the same point (:func:`_hidden_matches`).
MATCH_TOLERANCE = 1.0
#: A searched value replaces the current one only where its matching cost is lower by
#: more than this factor: small differences are noise, and flipping on them would break
#: the symmetry of the model (identical light fields must give δ1 = δ2 and zero flow;
#: on colour light fields δ1's tensor is the colour one and δ2's the luma's, see
#: ``Params.colour_tensor``, which breaks it slightly at edges).
FUSION_MARGIN = 0.8
#: The late sweep fusion (``Params.late_search``) runs only where the flow does not
#: match, and there δ1 and δ2 are suspect: the cross-time rows may have dragged them to
#: the neighbouring surface's depth, which can match the t1 samples about as well (an
#: outline pixel of `random-24`: 0.0119 against the sweep's 0.0121). The sweep's value
#: is taken unless its cost is higher by more than this factor (160×120, against 0.8:
#: δ1 / δ2 0.93 / 0.95× over 40 scenes, 0.94 / 0.94× over 64 others, 0.88 / 0.93× at
#: 320×240; 0.95: 0.95 / 0.95×).
LATE_SEARCH_MARGIN = 1.05
#: … and only where some pixel within LATE_SEARCH_REACH px already holds a value of the
#: same unknown within LATE_SEARCH_DEPTH (px per view step) of the sweep's
#: (:func:`lfsf.kernels.fusion.depth_nearby`): the value it corrects to is the
#: neighbouring surface's, which lies near. Elsewhere the sweep's value is a match of
#: its windows alone (an alias in a repeating or fine texture, sensor noise), and the
#: last warp cannot pull back a pixel taken that far: `paper` with photographs on its
#: objects, at (72, 78): δ1 −2.4 for 2.1, δ2 right. Paired geometric means of δ1 / δ2 /
#: EPE at 160×120 against the rule off (fortieth session): 20 scenes with photographs
#: 0.940 / 0.956 / 0.993; 10 with noise σ = 0.02 0.892 / 0.987 / 0.992; the 40
#: solid-textured ones 1.003 / 0.999 / 0.999, 64 others 0.992 / 0.995 / 0.996; 13 at
#: 320×240 1.014 / 1.015 / 0.999. A depth of 0.5: 0.963 / 0.983 / 0.996 with
#: photographs; 0.2 and 0.1: 0.950 and 0.982 for δ1; 3 px against 2 and 5: alike.
LATE_SEARCH_REACH = 3
LATE_SEARCH_DEPTH = 0.3
#: The estimate's δ1 and δ2 cleared of speckles at the very end
#: (``Params.speckle_radius``, :func:`lfsf.kernels.median.remove_speckles`): where fewer
#: than SPECKLE_SUPPORT of the 7 × 7 pixels around (radius 3) hold a value within
#: SPECKLE_DEPTH (px per view step) of the pixel's, it takes the window's median. A
#: depth no surface around shares is a stray pick of the data alone: an alias of the
#: sweeps' windows, a fusion's pick on a tie (`random-13` with photographs: a 3-pixel
#: cluster at δ 3.16 in a background at −1.79). Paired geometric means of δ1 / δ2 / EPE
#: at 160×120 against none (fortieth session): 20 scenes with photographs 0.729 / 0.790
#: / 1.000; the 40 solid-textured 0.903 / 0.966; `random-32…95` 0.953 / 0.954; 10 with
#: noise σ = 0.02 0.884 / 0.917. δ1 with photographs / solid-textured, at least 3, 5 or
#: 12 pixels in place of 8: 0.849 / 0.952, 0.751 / 0.919, 0.707 / 0.921 (radius 2 with
#: 4 of 25: 0.756 / 0.915); a depth of 0.2 (8 pixels) 0.776 / 0.951, 0.5 (5 pixels)
#: 0.797 / 0.939.
SPECKLE_DEPTH = 0.3
SPECKLE_SUPPORT = 8
#: The fit of each surface's motion (:func:`_fit_surface_motion`, ``Params.surface_fit``):
#: a pixel is a source where its flow's block residual over its own surface is below
#: SURFACE_FIT_GOOD times the standard deviation of the t1 centre view; the fit weighs
#: the neighbours within SURFACE_FIT_RADIUS steps (a step: the width / SURFACE_FIT_WIDTH
#: px, rounded, at least 1) by a Gaussian of SURFACE_FIT_SIGMA steps, slopes damped by
#: SURFACE_FIT_RIDGE (steps²); SURFACE_FIT_PASSES passes each time. 13×13 neighbours at
#: a step of 1/80 measured as 25×25 at 1/160, at a quarter of the time (docs/accuracy.md).
SURFACE_FIT_GOOD = 0.1
SURFACE_FIT_SIGMA = 3.0
SURFACE_FIT_RADIUS = 6
SURFACE_FIT_WIDTH = 80
SURFACE_FIT_RIDGE = 1.0
SURFACE_FIT_PASSES = 2
#: The points whose flow finds no match at t2 (:func:`_unmatched`): their block residual
#: over their own surface is above UNMATCHED_MEDIAN times the median residual of the
#: image (so that sensor noise, which raises every residual, does not make every point
#: unmatched) and above the surface fit's trust floor (SURFACE_FIT_GOOD times the
#: standard deviation of the t1 centre view); their δ2 comes from the final fill. Where
#: it is also above what a flow UNMATCHED_SLOPE px off would leave (that many times the
#: local mean |∇I1|), the flow is lost, and the fill gives the point its surface's
#: motion as well. Paired against the final fill without them (δ1 bit-identical): δ2
#: MSE 0.76 / 0.84 / 0.67× over 40 and 64 scenes at 160×120 and 13 at 320×240 by the
#: first; EPE 0.996 / 0.994 / 0.979× by the second (thirty-eighth session).
UNMATCHED_MEDIAN = 4.0
UNMATCHED_SLOPE = 1.0
#: The outlines' relabelling (:func:`_relabel_outlines`, ``Params.outline_relabel``):
#: each pixel's candidates are the states of the pixels within RELABEL_REACH px; one is
#: taken only where its δ1 differs by more than RELABEL_DEPTH_GAP px per view step and its
#: flow by more than RELABEL_FLOW_GAP px (surfaces whose motions differ by less are not
#: told apart by the centre views: `weak_texture` at 320×240 had its δ1 MSE doubled
#: without the flow gap), and where the pixel's flow residual is above RELABEL_FLOOR
#: times the match floor (:func:`_match_floor`; without one, the flow of a stereo pair,
#: zero up to rounding, found 'better' ones).
RELABEL_REACH = 2
RELABEL_DEPTH_GAP = 0.3
RELABEL_FLOW_GAP = 1.0
RELABEL_FLOOR = 0.1
#: Light fields whose joint intensity range spans less than this are stretched to [0, 1]
#: before anything else (:func:`_intensity_stretch`); wider ones are used as they are.
#: Every built-in and random scene spans more (the least: `random-0`, 0.22 at 80×60 and
#: 0.27 at 640×480; HCI antinous 0.87, the Lytro data 1.0), so their estimates are
#: unchanged. Stretching every scene spanning less than 0.5 instead measured worse
#: (δ1 / δ2 / EPE 1.15 / 1.13 / 1.03× over the 10 such scenes at 160×120).
MIN_INTENSITY_RANGE = 0.2
#: … and those spanning more than this (values far outside [0, 1]) are brought to [0, 1]
#: too; noise or processing that leaves values a little outside [0, 1] does not count.
MAX_INTENSITY_RANGE = 2.0
#: A change of exposure between t1 and t2 is undone (``Params.match_exposure``) where the
#: fitted map I ↦ g·I + b moves the t2 centre view's 5th or 95th percentile intensity by
#: more than this fraction of the two centre views' joint range (:func:`_exposure_change`).
EXPOSURE_CHANGE = 0.004
#: Where the fitted line I ↦ g·I + b leaves, in some band of t2's intensities, a median
#: residual of more than this fraction of the range (and the bands bow, below), a tone
#: curve through EXPOSURE_CURVE_BINS knots is found (:func:`_exposure_change`): a camera's
#: gamma or auto-exposure curve is no line. With ``Params.tone_curve`` t2 is matched by
#: that curve in place of the line; without it the progress tells of the bow. The
#: largest such residual: on 9 pairs of affine changes (none, ×1.1, ×0.6, ×1.2, ×0.8; noise σ 0.01–0.02; Lytro and synthetic
#: views) at most 0.0005; t2 = t2^0.8 0.022 (Lytro) and 0.010 (`paper`), t2^1.25 0.006.
#: On the helper's Lytro pair shifted by (3, 2) with t2^0.8, `fast`: EPE 0.958 with the
#: line, 0.417 with 8 knots, 0.100 with 16 (pixels 1 px off 9.0 → 0.4 %).
EXPOSURE_CURVE_MIN = 0.003
EXPOSURE_CURVE_BINS = 16
#: … and only where the bands' departures bow, a·(t² − t) + c over the knots' places t in
#: [0, 1], by more than this fraction of the range at the middle (|a|/4): on 80 pairs of
#: one exposure given ×1.2 (random-0…23 and the built-in four at 160×120 and 320×240, two
#: helpers' 24 scenes) 8 had a band stray beyond EXPOSURE_CURVE_MIN, bowing by at most
#: 0.0051 (one), 0.0022 the rest; gamma curves bowed 0.0037 (random-5, t2^1.2) to
#: 0.0149 (the helper's Lytro pair, t2^0.8).
EXPOSURE_CURVE_BOW = 0.003
#: The exposure pilot's warps (:func:`_exposure_change`; its other settings are the `flow`
#: preset's): 3, as it was measured with, whatever that preset's own.
EXPOSURE_WARPS = 3
#: The exposure pilot (flow only) runs on centre views box-averaged by the largest whole
#: factor that leaves at least this many pixels along their longer side (160–319) …
EXPOSURE_SIZE = 160
#: … and on views whose longer side is shorter than this only where their mean
#: brightness differs (SMALL_VIEWS_BRIGHTNESS, SMALL_VIEWS_CHANGE): at 64×48 the fit read
#: changes of up to 1.5 % on pairs of one exposure, at 96×72 up to 0.5 %.
EXPOSURE_MIN_SIZE = 120
#: … nor on views whose shorter side is shorter than this, and the box-averaging leaves at
#: least this many pixels along the shorter side: on pairs of one exposure the fit read
#: changes of 0.47–1.57 % on 3 of 4 scenes at 320×40 (averaged to 160×20), 0.76 % and
#: 0.72 % on `large_motion` at 200×40 and 120×40; at most 0.39 % with 60 or more rows.
EXPOSURE_MIN_SHORT = 48
#: Views shorter than EXPOSURE_MIN_SIZE are fitted only where their centre views differ
#: in mean brightness by more than this share (moving scenes of one exposure: 0–2.7 % on
#: the built-in scenes and `random-0…11` at 96×72, 6.0 % on `large_motion` at 64×48);
#: views too short to fit say so where it differs.
SMALL_VIEWS_BRIGHTNESS = 0.05
#: … and there the fit runs, but its change is acted on only beyond this share of the
#: range (not EXPOSURE_CHANGE): on the built-in scenes and `random-0…11` of one exposure
#: it read at most 1.3 % at 64×48 and 0.65 % at 96×72, and for t2 at 0.9 or 1.1 of t1's
#: exposure at least 6.5 % (a helper's two layers at 119×71, ×1.1: flow EPE 0.571 unmatched,
#: against 0.0138 at 120×71, where the fit ran).
SMALL_VIEWS_CHANGE = 0.03
#: A change of mean brightness left unmatched (views too small to measure one) that is a
#: warning, not only a note: moving scenes of one exposure read at most 6 %
#: (SMALL_VIEWS_BRIGHTNESS), t2 at 0.9 of t1's exposure 10–14 %.
UNMATCHED_BRIGHTNESS_WARNING = 0.25
#: The fit is refused where its two one-way slopes disagree, their product (r² for least
#: squares) below this: on 16 pairs of one exposure at 160×120 it was 0.974 or more
#: (median 0.998; with and without noise of σ = 0.02), and far below on mostly flat,
#: noisy images, where both slopes fall towards 0.
EXPOSURE_AGREEMENT = 0.9
#: … or where the gain it finds lies outside [1 / this, this]: three stops. On `paper` at
#: 160×120 (`fast`), t2 darkened to 0.45 and 0.35 of its exposure is fitted with g = 2.21
#: and 2.84 (flow EPE 0.111 and 0.128, against 0.091 at one exposure); with a cap of 2
#: it was refused and the EPE was 9.4 and 10.1. On 14 random scenes of one exposure, with
#: and without noise, the gains fitted were within 1 ± 0.01. With the cap at 4 (two
#: stops, until the thirty-first session) t2 at 0.2 was refused, though its gain was
#: fitted within 0.7 % and, matched, gave EPE 0.105 / 0.074 / 0.102 on `paper` /
#: `slanted` / `random-3` (`paper` preset, sensor noise σ = 0.01 added after the
#: exposure; 0.077 / 0.052 / 0.075 at one exposure; refused: 9–10 px); at 0.125 the
#: noise makes the slopes disagree on two of the three, which refuses them.
EXPOSURE_MAX_GAIN = 8.0
#: The pilot's structure–texture θ: with 0.95, 5 % of the structure stays in the matched
#: images, so its flow follows the texture and not the brightness.
EXPOSURE_THETA = 0.95
#: … and its block search's window radius (``Params.search_radius``, 1 in the presets): a
#: 3×3 window on those nearly high-passed images at the search's coarse level found no
#: match for a whole-scene pan of 14 px right and 14 up at 320×240 (pilot EPE 5.6 at
#: 160×120), and the fit read a 1.5 % change of exposure, applied, on a pair of one
#: exposure (0.9 and 1.5 % on two more such pans; another's fit refused a real one). With
#: 5×5 windows those read 0.001–0.01 %, and over 52 scenes at 160×120, 320×240 and
#: 640×480 the readings moved by at most 0.03 points, for 0.03 s more per pilot.
EXPOSURE_SEARCH_RADIUS = 2
#: The fit compares the two views blurred by a Gaussian of this σ (px of the pilot's
#: size): bilinear lookups at fractional positions blur I2(p + u) a little, which an
#: unblurred fit reads as a gain above 1 (up to 1.9 % on `slanted` at 320×240; 0.5 % with
#: σ = 3).
EXPOSURE_BLUR = 3.0
#: … and t2's by as much more as the scene grew from t1 to t2 (:func:`_flow_scale`), where
#: that is more than this fraction: a zoom of 5 % with no change of exposure had read as
#: 0.96·I + 0.02 (its flow's error 1.6× as large: 0.0375 against 0.0236 px with the `flow`
#: preset, a textured plane at 160×120), 10 % as 0.92·I + 0.04 (0.068 against 0.034). A
#: scene that shrinks still reads as a gain of 1.5–2 % (from what, not found).
EXPOSURE_SCALE_TOLERANCE = 0.02
#: A change of brightness over part of the view between t1 and t2 (a glare or a shadow
#: that comes or goes, a lamp turned on) is undone as well (:func:`_local_light`;
#: ``Params.match_exposure``): the residual of the t1 centre view against the t2 one at
#: the exposure pilot's flow, after the global match, is smoothed in t2's coordinates by
#: a Gaussian of LOCAL_LIGHT_SIGMA px of the pilot's size (robustly: residuals far from
#: the field count less, so that a pilot's flow error near a moving object is not
#: smoothed into it). The field is added to t2's views only where it *explains* more than
#: LOCAL_LIGHT_AREA of the view: pixels where it exceeds LOCAL_LIGHT_LEVEL of the range
#: and the residual less the field is under half the field (the texture under it then
#: matches). Scenes of one lighting read at most 1.2 % (`random-14` at 160×120, where
#: the pilot's flow fails on an object: there the residual is no smooth field, and
#: applying it cost the flow 1.2×); a broad glare of 0.1 at t2 read 4.6–14 %, of 0.2 and
#: 0.5 9–17 % (built-in scenes at 160×120, a Gaussian glare of σ = 0.08 of the width; the
#: flow's EPE 0.22 → 0.08 on `paper`, 0.52 → 0.17 on `weak_texture` at 0.2).
LOCAL_LIGHT_SIGMA = 4.0
LOCAL_LIGHT_LEVEL = 0.04
LOCAL_LIGHT_AREA = 0.03
#: … the residuals' robust scale (fraction of the range) and the reweighting rounds.
LOCAL_LIGHT_ROBUST = 0.03
LOCAL_LIGHT_ROUNDS = 3
#: … and only where the pilot's flow holds: on the most textured quarter of the pixels,
#: the median residual less the field, over their median gradient (a misregistration in
#: px), below this. With the glares above 0.04–0.17 px; on the Lytro scene's crop moved
#: by (30, 20) px, beyond the pilot's reach, 1.08 (its residual, two images' difference,
#: is smooth where they are, and the field had explained 31 % of the view: applied, the
#: estimate's flow went 0.03 → 27 px off).
LOCAL_LIGHT_MATCH = 0.4
#: … and only where what it explains is no thin band: the pixels whose (2·this + 1)²
#: box (of the pilot's size) is explained whole must be more than LOCAL_LIGHT_CORE_AREA
#: of the view. A helper's plane coming towards the camera (×1.5 in the image, brighter
#: than the wall behind it) left a band of −0.05 to −0.13 along its outline at t2 (wall
#: carried onto the plane by the pilot's smooth flow), explaining 4.8 % of the view, none
#: of it in such boxes; applied, the flow's EPE went 0.101 → 0.625. The glares above:
#: 1.2–9.2 % at 0.1, 3.7–10 % at 0.2 (a glare of 0.1 on `large_motion` then goes
#: unmatched); shadows (t2 × (1 − 0.4·G), σ = 0.2 of the width) 27–80 %.
LOCAL_LIGHT_CORE = 3
LOCAL_LIGHT_CORE_AREA = 0.02
#: The disparity sweep runs at full resolution: depth edges are where its value matters.
SWEEP_LEVEL = 0
#: ROF runs on each image padded by this many pixels of odd reflection (at most the
#: image's size − 1). With the Neumann boundary alone, TV flattens a smooth ramp over
#: its last ~2√(μ/slope) pixels before the border (22 px for HCI antinous's floor):
#: a texture pattern fixed to the image frame, the same in every view, which pulls the
#: disparity of weakly textured surfaces there towards 0. Measured: HCI antinous
#: MSE×100 2.61 → 2.49 (16 px; 48 px 2.47), its floor's share 0.33 → 0.24.
ROF_PAD = 16

#: σ_c of the colour weights of the last step on colour light fields
#: (``Params.colour_median_radius``), intensities in [0, 1]: HCI antinous MSE×100 2.32
#: (σ_c = 0.01), 2.33 (0.02), 2.41 (0.05); docs/accuracy.md.
COLOUR_SIGMA = 0.01
#: That step looks at windows whose δ spans more than this (px per view step).
COLOUR_JUMP = 0.3
#: … and is skipped for a colour light field whose channels are within this of each other
#: (intensities in [0, 1]; an 8-bit step is 0.0039) at 99 % of the centre view's pixels:
#: a grey light field stored as RGB.
GREY_CHROMA = 0.004


def kernel_modules(device: str) -> list:
    """The modules of :mod:`lfsf.kernels` whose kernels :func:`estimate_scene_flow` may
    launch on ``device`` (it loads them all at once at its start, :func:`lfsf.device.preload`).
    Whether each one is needed depends on the settings and the size: occlusion is not
    used for flow alone, and gains is not used on small views. :mod:`lfsf.kernels.data_groups`
    is only used where the data term keeps groups of pixels in vector registers (the CPU)."""
    from lfsf.kernels import (data_groups, data_term, fusion, gains, median, occlusion, pyramid, rof, sampling,
                              search, tgv)

    modules = [sampling, rof, pyramid, search, fusion, gains, occlusion, data_term, tgv, median]
    if not data_term.pixelwise(data_term.data_lanes(device)):
        modules.append(data_groups)
    return modules


def load_kernels(device: str, extra=(), say: Callable[[str], None] | None = None) -> str | None:
    """Compile, or read from Warp's kernel cache, the kernels of :func:`kernel_modules`
    and of the modules ``extra`` for ``device``, several modules at once
    (:func:`lfsf.device.preload`). ``say`` is told first where some are to be compiled
    (on a cold cache, 10–20 s of silence had passed before the line this returns).
    Returns a progress line where that took a second or more (it compiled them), else
    None."""
    def announce(cold: list[str]) -> None:
        say(f"compiling the kernels for {device} ({len(cold)} module{'s' if len(cold) > 1 else ''}; the first run "
            "only)…")

    seconds = _device.preload([*kernel_modules(device), *extra], device, None if say is None else announce)
    if seconds < 1.0:
        return None
    return f"kernels compiled for {device} in {seconds:.1f} s (once: Warp's kernel cache keeps them)"


#: The least sampling radius R (view steps) at which the view z-buffers
#: (``Params.visibility``) are used: on the small grids that allow less, they left out
#: more good rows than hidden ones. `fast` at 160×120, six scenes (paper, slanted,
#: random-1, -2, -5, large_motion), δ1 MSE with them against without, forty-seventh
#: session: R = 0.5 (2×2 views) 0.058/0.047/0.012/0.146/0.031/0.066 against
#: 0.046/0.035/0.0065/0.080/0.015/0.046, better without on each; R = 1 (3×3) better
#: without on each (large_motion 0.0105 → 0.0053, flow EPE 0.262 → 0.142; random-2's
#: EPE 0.137 → 0.183 the one loss); R = 2 (5×5) mixed, geometric mean of the δ1 ratios
#: 1.10 in favour of them (random-2 0.0051 against 0.0106); R = 4 (9×9) with them.
#: Two samples either side (``samples=(1, 2)``) on a 1×2 rig (R = 0.5): without them
#: δ1 0.05–0.13 against 0.13–0.42 on paper, slanted, random-2 and -5.
VISIBILITY_MIN_RADIUS = 2.0


def one_sided(phis) -> bool:
    """True where the side samples (φ ≠ 0) all lie in one open half-plane through the
    centre, as the single side view of two-view stereo (``circles=2, samples=(1, 1)``)
    does: then one occluder can hide a point from every side sample at once. The view
    z-buffers (``Params.visibility``) are not used then: a point they hide keeps no data
    at all, the regulariser fills it with the occluder's disparity, and, now as near as
    the occluder, it hides the points beside it in turn, so that wrong near blobs grow
    tens of pixels wide (two-view stereo, t1 = t2, 160×120, 8 scenes: δ1 MSE gmean 1.83
    with them, 0.14 without; `paper` 2.38 → 0.35). With samples on both sides of every
    line through the centre, some sample still sees each point; every preset's sampling
    is of that kind."""
    side = np.asarray(phis, np.float64).reshape(-1, 2)
    side = side[np.hypot(side[:, 0], side[:, 1]) > 1e-9]
    if len(side) == 0:
        return False
    angles = np.sort(np.arctan2(side[:, 1], side[:, 0]))
    gaps = np.diff(np.concatenate([angles, angles[:1] + 2.0 * np.pi]))
    return bool(np.max(gaps) > np.pi + 1e-9)


def _as_lightfield(lf, name: str) -> LightField:
    if isinstance(lf, LightField):
        if lf.source == "<array>":  # (made from an array: named as the argument it is, in messages)
            import copy

            lf = copy.copy(lf)
            lf.source = name
        return lf
    if isinstance(lf, (str, os.PathLike)):
        return read_lightfield(lf)
    if isinstance(lf, (tuple, list)) and lf and all(isinstance(x, (str, os.PathLike)) for x in lf):
        raise ValueError(f"{name}: got a {type(lf).__name__} of {len(lf)} paths; give each light field "
                         "as its own argument: estimate_scene_flow('t1.npz', 't2.npz')")
    if isinstance(lf, (bytes, bytearray)) or lf is None or np.ndim(lf) == 0:
        raise ValueError(f"{name}: expected a LightField, views (an array) or a path as str or "
                         f"path-like, got {type(lf).__name__} {lf!r:.60}")
    return LightField(np.asarray(lf), source=name)


#: On views decoded from a lenslet image (N across one lens pitch: a view step is pitch/N
#: sensor pixels, the micro-image's radius pitch/2), the samples stay within this fraction
#: of the micro-image's radius: R ≤ RIM_FRACTION·N/2 view steps (:func:`_rim_radius`).
#: Further out the views lie near the rims, darkened and mixed with the neighbouring
#: lenses. `scripts/lenslet_example.py`'s `paper` (GRBG mosaic), δ1 MSE (BadPix(0.07)) at
#: R = 2.5 / 3 / 3.5 / 4: pitch 9.6 px, 9 views 0.0126 (11.7 %) / 0.0121 (14.5 %) /
#: 0.0176 (49.6 %) / 0.0216 (68.0 %); pitch 14.3 px, 9 views 0.0082 (8.3 %) / 0.0068
#: (7.1 %) / 0.0070 (16.1 %) / 0.0100 (29.9 %); 13 views at R = 3.5 / 4.33 / 5 / 6:
#: 0.0058 / 0.0036 / 0.0045 / 0.0062 (22.1 %) (forty-fifth session). Real decoders'
#: users keep to a like share: EPINET's Lytro views are the central 9 of 15.
RIM_FRACTION = 2.0 / 3.0
#: Dark views (``Params.dark_view_fraction``): a helper's 9×9 scenes with the 32 views
#: outside the grid's inscribed circle black (fifty-first session) had δ1 MSE 6× worse
#: with `paper` (R = 4 reads views 3 steps off along both axes) and 65× with `lytro`;
#: dimmed to 0.3× with noise, 153× with `lytro`; at R = 2.75 as clean (R = 3 still
#: reads the four views at (±3, ±3) a little). Views darkened by vignetting are not
#: dark: 0.77 of the centre's at k = 0.3 and 0.67 at 0.45 (`synth.add_vignetting`, the
#: view gains match them), HCI antinous 0.99, the Lytro scene 0.97. The black level is
#: 0, or the pair's 0.1th percentile where that is below (views in [−1, 1], say): one
#: stray pixel does not move it.
DARK_LOW_PERCENTILE = 0.1


def _rim_radius(lf: LightField) -> float | None:
    """The largest sampling radius R (view steps) that keeps the samples off the
    micro-images' rims (:data:`RIM_FRACTION`), for a light field decoded from a lenslet
    image with N views across a lens (``meta["lens_views"]``, which :func:`lfsf.decode.decode`
    and a folder's ``decode.json`` give; kept where the views are cropped to the central
    ones); None for others."""
    n = lf.meta.get("lens_views")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 2 <= n <= MAX_LENS_VIEWS:
        return None
    return round(RIM_FRACTION * int(n) / 2.0, 6)


def _view_means(lf: LightField) -> np.ndarray:
    """(rows, cols): each view's mean over its pixels and colours (float64). (As a flat
    row per view: the mean over the axes of 81 RGB views of 640×480 took 1.2 s, this
    0.1 s.)"""
    views = lf.views
    rows, cols = views.shape[:2]
    if views.flags.c_contiguous:
        return views.reshape(rows, cols, -1).mean(axis=-1, dtype=np.float64)
    return views.mean(axis=tuple(range(2, views.ndim)), dtype=np.float64)


def _dark_views(lf1: LightField, lf2: LightField, fraction: float, least: float = 0.0) -> np.ndarray | None:
    """(rows, cols) bools: the views whose mean brightness is below ``fraction``
    (``Params.dark_view_fraction``) of the median of the views' means, at t1 or t2, their
    means taken above the black level (:data:`DARK_LOW_PERCENTILE`; ``least``: the pair's
    least value, where known); None where that median is not above it."""
    if least < 0.0:
        some = np.concatenate([lf.views[:, :, ::4, ::4].ravel() for lf in (lf1, lf2)])
        least = min(0.0, float(np.percentile(some, DARK_LOW_PERCENTILE)))
    else:
        least = 0.0
    dark = None
    for lf in (lf1, lf2):
        means = _view_means(lf) - least
        reference = float(np.median(means))
        if not reference > 0:
            return None
        this = means < fraction * reference
        dark = this if dark is None else dark | this
    return dark


def _radius_off_dark_views(params: Params, grid: tuple[int, int], dark: np.ndarray, radius: float) -> float | None:
    """The largest sampling radius, ``radius`` less a whole number of quarter view steps
    and at least 1, whose samples (:func:`lfsf.gains.sampled_views`) read no ``dark`` view;
    None where there is none."""
    rows, cols = grid
    flat = dark.reshape(-1)
    for k in range(int(math.floor(4 * (radius - 1.0) + 1e-9)) + 1):
        r = radius - 0.25 * k
        phis, _ = params.replace(radius=r).sample_offsets(grid)
        if not flat[sampled_views(phis, rows, cols)].any():
            return r
    return None


#: Float views beyond these bounds are taken for values on another scale (8- or 16-bit
#: numbers stored as floats), not for [0, 1] views with noise or an overshoot.
UNIT_RANGE_SLACK = (-0.5, 1.5)


def far_outside_unit(values: np.ndarray) -> tuple[float, float] | None:
    """The range (lo, hi) of float ``values``' finite values where it reaches beyond
    :data:`UNIT_RANGE_SLACK` (0…255 given as floats); None where it does not, or where no
    value is finite. What the peers' wrappers and ``viz.save_png`` refuse."""
    finite = values[np.isfinite(values)]
    if not finite.size:
        return None
    lo, hi = float(finite.min()), float(finite.max())
    return (lo, hi) if lo < UNIT_RANGE_SLACK[0] or hi > UNIT_RANGE_SLACK[1] else None


#: Set while :func:`pilot_estimate` runs (per thread and task): its views need no checks.
_IN_PILOT: contextvars.ContextVar[bool] = contextvars.ContextVar("lfsf_in_pilot", default=False)


def pilot_estimate(lf1, lf2, params: Params, device: str) -> "SceneFlow":
    """:func:`estimate_scene_flow` on views the estimator made itself (the exposure
    pilot's, the view gains' pilot's), without its warnings about the input (views outside
    [0, 1], their layout): the user's views were warned about once
    already, and these, scaled by the pilot, are none of theirs (a second pair of warnings
    named 'light field 1' and a range the user never gave). :data:`_IN_PILOT` says so,
    per thread: a filter of the warnings module would be every thread's."""
    token = _IN_PILOT.set(True)
    try:
        return estimate_scene_flow(lf1, lf2, params, device=device)
    finally:
        _IN_PILOT.reset(token)


def _warn_out_of_unit_range(source: str, lo: float, hi: float, stretched: bool, say, views=None) -> None:
    """Warn (at the caller of :func:`estimate_scene_flow`) where a light field's views lie
    far outside [0, 1], where lfsf expects them: what is done with them, stretched to
    [0, 1] by the pair's range (:func:`_intensity_stretch`) or used as they are, is not
    the same as the views divided by their scale (a dark capture's 0…120 of 255 comes out
    as 0…1, not 0…0.47; Γ and the ROF weight μ read intensities in [0, 1]). Unsigned
    integer views are scaled by their type's maximum and never reach here (signed ones,
    below 0, do). Where a few values lie far beyond the rest (``views``: a hot pixel of
    1e3 in views of [0, 1]), the stretch leaves the rest nearly flat, and the warning
    says so: the estimate had been wrecked by one pixel under a warning of the range."""
    if (UNIT_RANGE_SLACK[0] <= lo and hi <= UNIT_RANGE_SLACK[1]) or _IN_PILOT.get():
        return
    done = ("stretched to [0, 1] by the two light fields' joint range" if stretched
            else "used as they are")
    hint = (" (divide by 255, or 65535, if they are 8-bit or 16-bit values, or give them as integers, "
            "which are scaled by their type's maximum)" if hi > UNIT_RANGE_SLACK[1] else "")
    if views is not None and hi > lo:
        # (of a sample: every value of 9×9 views of 640×480 took 2.2 s and 100 MB)
        flat = np.asarray(views).reshape(-1)
        sample = flat[::max(1, flat.size // OUTLIER_SAMPLE)]
        values = sample[np.isfinite(sample)]
        low, high = (float(v) for v in np.percentile(values, (0.1, 99.9))) if values.size else (lo, hi)
        if high - low < OUTLIER_SPAN * (hi - lo):
            hint += (f"; 99.8 % of the values lie within {low:.4g}…{high:.4g}, under {OUTLIER_SPAN:.0%} of that "
                     "range: a few stray values (hot pixels?) set the stretch and leave the rest nearly flat, and "
                     "the estimate will be poor: clip them")
    # ("views", not "float views": signed integers scaled by their maximum come here too)
    _warn(f"{source}: views range {lo:.4g}…{hi:.4g}, where lfsf expects [0, 1]; {done}{hint}", say)


#: Where 99.8 % of the views' values span less than this share of their whole range, a
#: few stray values set :func:`_intensity_stretch`, and the warning of the range says so.
OUTLIER_SPAN = 0.05
#: Values the percentiles of that test are taken over, about (every k-th of the views').
OUTLIER_SAMPLE = 1 << 20


def data_weights(params: Params, n_samples: int) -> np.ndarray:
    """(λ1, λ2, λ3) / S per sample, float32 (S, 3): the data term's row weights
    (MODEL.md §3), with the stereo rows of φ = 0 (sample 0) at 0, where both residuals
    vanish identically, and the side samples' ρ3 rows at ``lambda3_side`` · λ3 / S."""
    weights = np.tile(np.array([params.lambda1, params.lambda2, params.lambda3], np.float32) / n_samples,
                      (n_samples, 1))
    weights[0, :2] = 0.0
    if params.lambda3_side != 1.0:
        weights[1:, 2] = np.float32(params.lambda3 * params.lambda3_side / n_samples)
    return weights


def pyramid_sizes(height: int, width: int, params: Params) -> list[tuple[int, int]]:
    """Level sizes (h, w), finest first: scaled by η_s while the shorter side stays at
    least ``min_size`` (and at most ``max_levels`` levels)."""
    sizes = [(height, width)]
    while True:
        h, w = sizes[-1]
        nh = int(round(height * params.pyramid_scale ** len(sizes)))
        nw = int(round(width * params.pyramid_scale ** len(sizes)))
        if min(nh, nw) < params.min_size or (nh, nw) == (h, w):
            break
        if params.max_levels and len(sizes) >= params.max_levels:
            break
        sizes.append((nh, nw))
    return sizes


def rof_denoise(stack, mu: float, iterations: int, device: str, width: int | None = None):
    """u = argmin Σ|∇u| + 1/(2μ) Σ(u − f)² of every image f of a (n, h, w) stack, by
    ``iterations`` steps of the accelerated primal–dual algorithm (Chambolle & Pock 2011,
    Alg. 2): the fidelity is 1/μ-strongly convex, so after each step τ shrinks and σ grows
    by ϑ = 1/√(1 + 2τ/μ) (τσ‖∇‖² ≤ 1 kept), which converges as 1/N² where fixed steps
    converge as 1/N. Unconverged, the structure part blurs strong edges, and their halo
    in the texture part moves with the nearer surface: the foreground's disparity then
    spreads over the background (``weak_texture`` δ1 MSE 0.041 with 60 fixed steps,
    0.014 with 60 accelerated ones, stereo at 320×240).

    ``width``: the images' width, where the stack's rows are longer (default: w). On the
    CPU the steps take a row's pixels in groups of :data:`lfsf.kernels.rof.ROF_LANES`
    (the same arithmetic per pixel), in rows of a multiple of it (:func:`_rof_rows`); the
    lanes past ``width`` are left out of every stencil. A stack of other rows, or one
    that is not a contiguous float32 array (the steps read it as vectors of 8), is
    copied into such rows first (and u copied back). Returns u with the stack's shape."""
    from lfsf.kernels import rof

    wp = _device.warp()
    n, h, w = stack.shape
    width = w if width is None else int(width)
    if not 1 <= width <= w:
        raise ValueError(f"rof_denoise: images {width} wide in rows of {w} values")
    lanes = _device.is_cpu(device)
    if lanes and (w % rof.ROF_LANES or not stack.is_contiguous or stack.dtype != wp.float32):
        rows = wp.zeros((n, h, _rof_rows(w, device)), dtype=float, device=device)
        _device.launch_rows(rof.pad_odd, dim=(n * h, w), inputs=[stack, 0], outputs=[rows], device=device)
        u = rof_denoise(rows, mu, iterations, device, width=width)
        return wp.array(np.ascontiguousarray(u.numpy()[..., :w]), dtype=float, device=device)
    u = wp.clone(stack)
    u_bar = wp.clone(stack)
    tau = sigma = 1.0 / math.sqrt(8.0)
    if lanes:
        groups = w // rof.ROF_LANES

        f8, u8, ub8 = (_device.vector_view(a, rof.rof_lane, (n, h, groups)) for a in (stack, u, u_bar))
        px = wp.zeros((n, h, groups), dtype=rof.rof_lane, device=device)
        py = wp.zeros((n, h, groups), dtype=rof.rof_lane, device=device)
    else:
        if width != w:
            raise ValueError(f"rof_denoise on {device} takes whole rows (width {width}, rows of {w})")
        span, per_row = _device.row_span(device, w)
        p = wp.zeros((n, h, w), dtype=wp.vec2, device=device)
    for _ in range(iterations):
        relax = 1.0 / math.sqrt(1.0 + 2.0 * tau / mu)
        if lanes:
            _device.launch_rows(rof.rof_dual_lanes, dim=(n * h, 1), inputs=[ub8, width, sigma], outputs=[px, py],
                                device=device)
            _device.launch_rows(rof.rof_primal_lanes, dim=(n * h, 1), inputs=[f8, px, py, width, tau, mu, relax],
                                outputs=[u8, ub8], device=device)
        else:
            _device.launch_rows(rof.rof_dual_step, dim=(n * h, per_row), inputs=[u_bar, sigma, span], outputs=[p],
                                device=device)
            _device.launch_rows(rof.rof_primal_step, dim=(n * h, per_row), inputs=[stack, p, tau, mu, relax, span],
                                outputs=[u, u_bar], device=device)
        tau, sigma = relax * tau, sigma / relax
    return u


def _rof_rows(width: int, device: str) -> int:
    """The length of the rows that :func:`rof_denoise` takes images ``width`` wide in: a
    multiple of :data:`lfsf.kernels.rof.ROF_LANES` on the CPU, ``width`` on CUDA."""
    from lfsf.kernels import rof

    return -(-width // rof.ROF_LANES) * rof.ROF_LANES if _device.is_cpu(device) else width


def sampling_launch(views, rows: int, cols: int, phis, out, device: str):
    """How out[s] = the sub-aperture image at φ_s (``phis``) of ``views`` (rows · cols, h,
    w), both stored contiguously, is launched on ``device``: (kernel, dim, inputs). On
    the CPU a thread walks whole rows of a sample
    (:func:`lfsf.kernels.sampling.sample_subaperture`), on CUDA a thread takes a pixel of
    every sample (:func:`lfsf.kernels.sampling.sample_subaperture_pixel`)."""
    from lfsf.kernels import sampling

    n, h, w = out.shape
    if _device.is_cpu(device):
        span, per_row = _device.row_span(device, w)
        return sampling.sample_subaperture, (n * h, per_row), [views, rows, cols, phis, span]
    return sampling.sample_subaperture_pixel, (h, w), [views, rows, cols, phis]


def touched_views(phis, rows: int, cols: int) -> list[int]:
    """The views (indices a·cols + b) that :func:`lfsf.kernels.sampling.sample_subaperture`
    reads for the angular offsets ``phis``: the four around each sample (its a0, a1, b0,
    b1, :func:`lfsf.kernels.sampling.four_views`), those of weight 0 among them too,
    whose values it multiplies by 0. A superset of :func:`lfsf.gains.sampled_views`."""
    used = set()
    for xi, eta in np.asarray(phis, np.float32).reshape(-1, 2):
        a = min(max(np.float32(0.5) * np.float32(rows - 1) + eta, np.float32(0.0)), np.float32(rows - 1))
        b = min(max(np.float32(0.5) * np.float32(cols - 1) + xi, np.float32(0.0)), np.float32(cols - 1))
        a0, b0 = min(int(a), max(rows - 2, 0)), min(int(b), max(cols - 2, 0))
        for ai in (a0, min(a0 + 1, rows - 1)):
            for bi in (b0, min(b0 + 1, cols - 1)):
                used.add(ai * cols + bi)
    return sorted(used)


def sample_views(views, rows: int, cols: int, phis, out, device: str) -> None:
    """out[s] = the sub-aperture image at φ_s (``phis``) of ``views`` (:func:`sampling_launch`)."""
    kernel, dim, inputs = sampling_launch(views, rows, cols, phis, out, device)
    _device.launch_rows(kernel, dim=dim, inputs=inputs, outputs=[out], device=device)


def _structure_texture(stack, params: Params, device: str):
    """Texture part T = f − θ·ROF(f) of every image of a (n, h, w) stack (MODEL.md §3),
    ROF on the image padded by odd reflection (:data:`ROF_PAD`)."""
    from lfsf.kernels import rof

    wp = _device.warp()
    if params.texture_theta <= 0 or params.rof_iterations <= 0:
        return stack
    n, h, w = stack.shape
    pad = max(0, min(ROF_PAD, h - 1, w - 1))
    hp, wp_ = h + 2 * pad, w + 2 * pad
    rows = _rof_rows(wp_, device)
    padded = stack
    if pad or rows != w:
        # (zeros past the padded width: no stencil reads them, but no garbage either)
        padded = (wp.zeros if rows != wp_ else wp.empty)((n, hp, rows), dtype=float, device=device)
        _device.launch_rows(rof.pad_odd, dim=(n * hp, wp_), inputs=[stack, pad], outputs=[padded], device=device)
    u = rof_denoise(padded, params.rof_weight, params.rof_iterations, device, width=wp_)
    del padded
    texture = wp.empty_like(stack)
    _device.launch_rows(rof.texture_part, dim=(n * h, w), inputs=[stack, u, params.texture_theta, pad],
                        outputs=[texture], device=device)
    return texture


def _mean_gradient(img: np.ndarray) -> float:
    """The mean absolute forward difference of a 2-D image, along x and y averaged."""
    return 0.5 * (float(np.mean(np.abs(np.diff(img, axis=1)))) + float(np.mean(np.abs(np.diff(img, axis=0)))))


def _normalise_contrast(stack, params: Params, device: str):
    """Scale the whole (texture) stack so that the t1 centre view's mean absolute image
    gradient is ``params.contrast``: the data weights λ then mean the same for dim and
    bright, weakly and strongly textured scenes, with or without the texture split. The
    gradient, not the spread of values, measures what matching sees (large smooth
    shading has a wide spread and no texture). One factor for every image, so that
    brightness constancy between views and times is kept. The stack is scaled in place
    (on the device: only the centre view comes to the host) and returned."""
    from lfsf.kernels import rof

    if params.contrast <= 0:
        return stack
    gradient = _mean_gradient(stack[0].numpy())
    if not np.isfinite(gradient) or gradient < 1e-7:
        return stack  # a flat image: nothing to match, nothing to scale
    n, h, w = stack.shape
    _device.launch_rows(rof.scale_values, dim=(n * h, w), inputs=[float(np.float32(params.contrast / gradient))],
                        outputs=[stack], device=device)
    return stack


def _downsample(stack, size, device: str):
    from lfsf.kernels import pyramid

    wp = _device.warp()
    n, h, w = stack.shape
    ratio = max(h / size[0], w / size[1])
    sigma = max(ratio / 3.0, 0.5)
    radius = int(math.ceil(3.0 * sigma))
    out = wp.empty((n, size[0], size[1]), dtype=float, device=device)
    if _device.is_cpu(device):  # a row per thread, the window's weights kept along it
        span, per_row = _device.row_span(device, size[1])
        _device.launch_rows(pyramid.downsample_rows, dim=(n * size[0], per_row), inputs=[stack, sigma, radius, span],
                            outputs=[out], device=device)
        return out
    _device.launch_rows(pyramid.downsample, dim=(n * size[0], size[1]), inputs=[stack, sigma, radius],
                        outputs=[out], device=device)
    return out


def _upsample_state(arrays: list[np.ndarray], size, scales, device: str) -> list[np.ndarray]:
    """Bilinearly upsample (h, w, 4) fields to ``size``, multiplying component k by scales[k]."""
    from lfsf.kernels import pyramid

    wp = _device.warp()
    out = []
    for arr in arrays:
        h, w, _ = arr.shape
        # planes that are 0 everywhere (flow only: δ1, δ2) stay 0 (+0 · scale): not upsampled
        live = [k for k in range(4) if np.any(arr[..., k])] or [0]
        coarse = wp.array(np.ascontiguousarray(np.moveaxis(arr[..., live], -1, 0)), dtype=float, device=device)
        fine = wp.empty((len(live), size[0], size[1]), dtype=float, device=device)
        _device.launch_rows(pyramid.upsample, dim=(len(live) * size[0], size[1]), inputs=[coarse, 1.0],
                            outputs=[fine], device=device)
        full = np.zeros((size[0], size[1], 4), np.float32)
        full[..., live] = np.moveaxis(fine.numpy(), 0, -1)
        out.append(full * np.asarray(scales, np.float32))
    return out


def _windowed_cost(kernel, inputs, count: int, size, search_radius: int, device: str,
                   columns: int | None = None):
    """Per-pixel matching costs of ``count`` candidates (a cost kernel of
    :mod:`lfsf.kernels.search`, which walks a row span per thread), averaged over
    (2r+1)² windows, and of those the best window that holds the pixel (shiftable
    windows): (count, h, w). A window centred on a pixel next to a depth edge reaches
    over the edge, and the nearer surface's texture, matched at its own disparity, makes
    that disparity win a pixel or two into the background; one of the windows beside
    it stays on the pixel's own side (a layered scene's δ1 MSE at one pixel from the
    edge fell from 3.95 to 0.85, HCI antinous MSE×100 from 9.9 to 5.0). ``columns``: how
    many columns a thread of ``kernel`` walks (default: :func:`lfsf.device.row_span`'s)."""
    wp = _device.warp()
    h, w = size
    cost = wp.empty((count, h, w), dtype=float, device=device)
    lanes = _device.row_span(device, w)[0] if columns is None else columns
    _device.launch_rows(kernel, dim=(count * h, -(-w // lanes)), inputs=[*inputs, lanes], outputs=[cost],
                        device=device)
    _best_windows(cost, search_radius, device)
    return cost


def _best_windows(cost, search_radius: int, device: str, smooth=None) -> None:
    """Per-pixel costs (count, h, w), a device array, replaced in place by their means
    over (2r+1)² windows, and of those the best window that holds the pixel (shiftable
    windows, :func:`_windowed_cost`); left as they are with r ≤ 0. ``smooth``: scratch of
    ``cost``'s shape (default: allocated here)."""
    from lfsf.kernels import search

    if search_radius <= 0:
        return
    count, h, w = cost.shape
    span, per_row = _device.row_span(device, w)
    if smooth is None:
        smooth = _device.warp().empty_like(cost)
    box_sum, box_min = search.box_kernels(device)
    _device.launch_rows(box_sum, dim=(count * h, per_row), inputs=[cost, search_radius, span],
                        outputs=[smooth], device=device)
    _device.launch_rows(box_min, dim=(count * h, per_row), inputs=[smooth, search_radius, span],
                        outputs=[cost], device=device)


def sweep_shifts(candidates: np.ndarray, phis: np.ndarray) -> np.ndarray:
    """The shifts of :func:`lfsf.kernels.search.sweep_cost`: sample s of candidate k looks
    at q − δ_k φ_s, a constant shift (a, b) + (f, g), whole part and fraction ∈ [0, 1):
    (K, S, 4) float32."""
    offsets = -np.asarray(candidates, np.float32)[:, None, None] * np.asarray(phis, np.float32)[None, :, :]
    whole = np.floor(offsets)
    return np.concatenate([whole, offsets - whole], -1).astype(np.float32)


def _sweep(samples, phis, radius_used: float, disparity_range: float, search_radius: int, device: str,
           visibility_margin: float | None = None):
    """Plane-sweep disparity of a (S, h, w) sample stack (the t1 or t2 light field in its
    own frame): winner-take-all over windowed costs, candidates spaced so that the outer
    samples move by half a pixel from one to the next. The first pass leaves occluded
    samples out by the best half; with ``visibility_margin`` a second pass leaves out
    those that the first pass's disparities cover (view z-buffers, ``Params.visibility``)."""
    from lfsf.kernels import fusion, search
    from lfsf.kernels.common import vec8

    wp = _device.warp()
    n, h, w = samples.shape
    if not samples.is_contiguous:  # (the sweep kernels read rows of it as contiguous floats)
        samples = wp.clone(samples)
    step = 0.5 / max(radius_used, 1e-6)
    count = int(math.ceil(disparity_range / step))
    cands = np.arange(-count, count + 1, dtype=np.float32) * np.float32(step)
    candidates = wp.array(cands, dtype=float, device=device)
    shifts = wp.array(sweep_shifts(cands, phis.numpy()), dtype=wp.vec4, device=device)
    masks = wp.empty(n, dtype=vec8, device=device)
    _device.launch_rows(search.sample_half_planes, dim=n, inputs=[phis], outputs=[masks], device=device, bands=1)
    half_kernel, visible_kernel, columns = search.sweep_kernels(device)
    smooth = _windowed_cost(half_kernel, [samples, shifts, masks], len(cands), (h, w), search_radius, device, columns)
    best = wp.empty((h, w), dtype=float, device=device)
    best_cost = wp.empty((h, w), dtype=float, device=device)
    _device.launch_rows(search.select_disparity, dim=(h, w), inputs=[smooth, candidates], outputs=[best, best_cost],
                        device=device)
    if visibility_margin is not None and n > 1:
        del smooth
        unknowns = wp.zeros((h, w), dtype=wp.vec4, device=device)
        _device.launch_rows(fusion.with_plane, dim=(h, w), inputs=[unknowns, 0, best], outputs=[unknowns],
                            device=device)
        zbuf = _view_zbuffer(unknowns, 0, False, phis, device)
        smooth = _windowed_cost(visible_kernel, [samples, shifts, candidates, zbuf, visibility_margin],
                                len(cands), (h, w), search_radius, device, columns)
        _device.launch_rows(search.select_disparity, dim=(h, w), inputs=[smooth, candidates],
                            outputs=[best, best_cost], device=device)
    return best.numpy()


def _view_zbuffer(x, component: int, flow: bool, phis, device: str):
    """View z-buffers (S, h, w) of the disparity map x[component] (x: the unknowns, a
    vec4 (h, w) device array) whose points sit at p (+ x's flow, at t2, with ``flow``)
    in the centre view (:func:`lfsf.kernels.occlusion.splat_views`)."""
    from lfsf.kernels import occlusion

    wp = _device.warp()
    h, w = x.shape
    n = phis.shape[0]
    zbuf = wp.full((n, h, w), occlusion.EMPTY, dtype=float, device=device)
    span, per_row = _device.row_span(device, w)
    _device.launch_rows(occlusion.splat_views, dim=(n, h, per_row), inputs=[x, component, int(flow), phis, span],
                        outputs=[zbuf], device=device)  # bands of whole samples: the atomics never meet
    return zbuf


def _window_cost(samples, phis, disparity, offset, search_radius: int, device: str, zbuf=None, margin: float = 0.0):
    """Windowed matching cost (h, w) (a device array) of a per-pixel disparity field
    (a float (h, w) device array) at p + the flow of ``offset`` (vec4 (h, w), the
    unknowns): by the best half, or with view z-buffers ``zbuf`` by the samples they
    leave visible."""
    from lfsf.kernels import search

    wp = _device.warp()
    n, h, w = samples.shape
    zero = wp.zeros(1, dtype=float, device=device)
    if zbuf is None:
        kernel, inputs = search.disparity_cost, [samples, phis, zero, disparity, offset]
    else:
        kernel, inputs = search.disparity_cost_visible, [samples, phis, zero, disparity, offset, zbuf, margin]
    return _windowed_cost(kernel, inputs, 1, (h, w), search_radius, device)[0]


def _resize_plane(image, size, scale: float, device: str):
    """Resample a (h, w) map (a float device array) to ``size`` (Gaussian-prefiltered
    when shrinking, bilinear when growing) and multiply it by ``scale``: a new (size)
    device array."""
    from lfsf.kernels import pyramid, rof

    wp = _device.warp()
    h, w = image.shape
    src = image.reshape((1, h, w))
    if (h, w) == tuple(size):
        out = wp.clone(src)
    elif size[0] < h:
        out = _downsample(src, size, device)
    else:
        out = wp.empty((1, size[0], size[1]), dtype=float, device=device)
        _device.launch_rows(pyramid.upsample, dim=(size[0], size[1]), inputs=[src, 1.0], outputs=[out], device=device)
    _device.launch_rows(rof.scale_values, dim=(size[0], size[1]), inputs=[float(np.float32(scale))], outputs=[out],
                        device=device)
    return out[0]


def _resize_map(image: np.ndarray, size, scale: float, device: str) -> np.ndarray:
    """:func:`_resize_plane` of a NumPy map, to NumPy."""
    wp = _device.warp()
    src = wp.array(np.ascontiguousarray(image, np.float32), dtype=float, device=device)
    return _resize_plane(src, size, scale, device).numpy()


def _bilinear(image: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """image at the real positions (px, py) by bilinear interpolation, clamped to the
    image (NumPy; the arithmetic in the inputs' precision)."""
    h, w = image.shape
    px = np.clip(px, 0, w - 1)
    py = np.clip(py, 0, h - 1)
    x0 = np.minimum(px.astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(py.astype(np.int64), max(h - 2, 0))
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx, fy = px - x0, py - y0
    top = (1 - fx) * image[y0, x0] + fx * image[y0, x1]
    bottom = (1 - fx) * image[y1, x0] + fx * image[y1, x1]
    return (1 - fy) * top + fy * bottom


def _sample_at_flow(image: np.ndarray, x: np.ndarray) -> np.ndarray:
    """image(p + (u, v)) by bilinear interpolation, clamped (NumPy; once per level)."""
    h, w = image.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return _bilinear(image, xx + x[..., 2], yy + x[..., 3]).astype(np.float32)


def flow_search_level(sizes: list[tuple[int, int]], flow_range: float, pyramid_scale: float) -> int:
    """The pyramid level (index into ``sizes``, (h, w) finest first, level k scaled by
    η_s^k = ``pyramid_scale`` ** k) of the flow search: the finest on which the whole range
    is at most FLOW_SEARCH_HALF pixels and which is at most FLOW_SEARCH_WIDTH pixels wide
    or scaled by at most FLOW_SEARCH_SCALE (else the coarsest).

    The range by the level's scale η_s^k, not by its rounded size: 159 px halve to 80, and
    24 · 80 / 159 = 12.08 px failed the range by the rounding alone. One image width in
    four between 99 and 319 px then searched a level coarser than its neighbours, and
    lost fast objects (`large_motion` at 159×119, `paper` preset: flow EPE 0.98 against
    0.09 with the search on the 80-px level)."""
    return next((k for k, (_h, w) in enumerate(sizes)
                 if flow_range * pyramid_scale ** k <= FLOW_SEARCH_HALF * (1 + 1e-9)
                 and (w <= FLOW_SEARCH_WIDTH or pyramid_scale ** k <= FLOW_SEARCH_SCALE * (1 + 1e-9))),
                len(sizes) - 1)


def searched_flow_range(params: Params, sizes: list[tuple[int, int]]) -> float:
    """The flow search's range in pixels on pyramid levels ``sizes`` (finest first):
    ``Params.flow_search_range`` of the views' size, but a range that the size sets (not
    ``flow_range``) goes no further than the coarsest level can search, ±MAX_FLOW_SEARCH_HALF
    of its pixels (a strip of 2600×14 px has one level: ±65 px there had been an error)."""
    reach = MAX_FLOW_SEARCH_HALF / params.pyramid_scale ** (len(sizes) - 1)
    return max(params.flow_range, min(params.flow_search_range(sizes[0]), reach))


def _shared_range_note(params: Params, longer: int, flow_range: float) -> str:
    """The Note of a flow search whose range ``flow_range`` the views' longer side set
    (``Params.flow_range_share``), naming the bound that cut it, if any: MAX_FLOW_RANGE or
    what the pyramid's coarsest level can search."""
    wanted = params.flow_range_share * longer
    bound = ("" if wanted <= flow_range else f" ({wanted:g}, at most " + (
        f"{MAX_FLOW_RANGE:g})" if flow_range == MAX_FLOW_RANGE else f"{flow_range:g} on this pyramid)"))
    return (f"flow search ±{flow_range:g} px: flow_range_share {params.flow_range_share:g} of the views' {longer} px"
            f"{bound}, more than flow_range {params.flow_range:g}")


def flow_search_half(flow_range: float, pyramid_scale: float, level: int,
                     size: tuple[int, int] | None = None) -> int:
    """The flow search's half-width in whole pixels on pyramid level ``level``: the range
    at the level's scale η_s^k, rounded up (:func:`flow_search_level`), and with the
    level's ``size`` (h, w) at most its longer side less one: a longer shift moves every
    window off the level (a flow_range of 512 px on a 64×48 image)."""
    half = max(1, int(math.ceil(flow_range * pyramid_scale ** level * (1 - 1e-9))))
    return half if size is None else min(half, max(1, max(size) - 1))


def _flow_search(centre1, centre2, half: int, search_radius: int, device: str, ambiguity: bool = False):
    """Whole-pixel block matching of the centre views over a (2n+1)² window of
    displacements (windowed |I1(p) − I2(p + u)|), refined to sub-pixel: (h, w, 2). One
    pass over the shifts keeps each pixel's best; no cost volume is stored.

    With ``ambiguity``, (flow, ambiguous): ambiguous (bool (h, w)) where, over most of the
    FLOW_AMBIGUITY_AREA² pixels around, the best cost is at least FLOW_AMBIGUITY times
    that of the runner-up at least FLOW_AMBIGUITY_DISTANCE steps away
    (:func:`lfsf.kernels.search.flow_search`), or the runner-up's is below
    FLOW_AMBIGUITY_FLOOR times the standard deviation of ``centre1``."""
    from lfsf.kernels import search

    wp = _device.warp()
    h, w = centre1.shape
    span, per_row = _device.row_span(device, w)
    best_cost = wp.empty((h, w), dtype=float, device=device)
    best_k = wp.empty((h, w), dtype=int, device=device)
    best = wp.empty((h, w), dtype=wp.vec2, device=device)
    second_cost = wp.empty((h, w), dtype=float, device=device)
    second_k = wp.empty((h, w), dtype=int, device=device)
    if _device.is_cpu(device):  # a row per thread, the row's column sums per shift in vector code
        colc = wp.empty((h, w + 2 * search_radius), dtype=float, device=device)
        _device.launch_rows(search.flow_search_rows, dim=(h, 1),
                            inputs=[centre1, centre2, half, search_radius, FLOW_AMBIGUITY_DISTANCE, colc],
                            outputs=[best_cost, best_k, best, second_cost, second_k], device=device)
    else:
        _device.launch_rows(search.flow_search, dim=(h, per_row),
                            inputs=[centre1, centre2, half, search_radius, FLOW_AMBIGUITY_DISTANCE, span],
                            outputs=[best_cost, best_k, best, second_cost, second_k], device=device)
    if not ambiguity:
        return best.numpy()
    second = second_cost.numpy()
    floor = FLOW_AMBIGUITY_FLOOR * float(np.std(centre1.numpy()))
    tied = ((best_cost.numpy() >= FLOW_AMBIGUITY * second) | (second < floor)).astype(np.float32)
    return best.numpy(), box_mean(tied, FLOW_AMBIGUITY_AREA) > 0.5


def _hidden_matches(forward: np.ndarray, backward: np.ndarray, tolerance: float = MATCH_TOLERANCE) -> np.ndarray:
    """Pixels of t1 whose searched match belongs to another point (bool (h, w)).

    ``forward`` is the search from t1 to t2 (u(p): p ↦ q = p + u(p)), ``backward`` the
    search from t2 to t1 on t2's grid. Pixel p is flagged where the backward search
    from q leads to another pixel, p' = q + u_b(q) with |u(p) + u_b(q)| > ``tolerance``,
    and that pixel leads back to q, |u_b(q) + u(p')| ≤ ``tolerance``. Two points cannot
    both be seen at q; p' is, so p is hidden at t2, and what its search found is the
    point that hides it. Only flags that fill a 2×2 block of pixels are kept: a single
    flag is block matching's noise, hidden regions are areas."""
    h, w = forward.shape[:2]
    at_q = np.zeros((h, w, 4), np.float32)
    at_q[..., 2:] = forward
    back_at_q = np.stack([_sample_at_flow(backward[..., c], at_q) for c in (0, 1)], -1)
    # for every pixel q of t2: does its backward match p' lead back to it?
    at_p = np.zeros((h, w, 4), np.float32)
    at_p[..., 2:] = backward
    forward_at_p = np.stack([_sample_at_flow(forward[..., c], at_p) for c in (0, 1)], -1)
    owned = (np.hypot(*np.moveaxis(backward + forward_at_p, -1, 0)) <= tolerance).astype(np.float32)
    flagged = ((np.hypot(*np.moveaxis(forward + back_at_q, -1, 0)) > tolerance)
               & (_sample_at_flow(owned, at_q) > 0.99))
    return _keep_blocks(flagged)


def _keep_blocks(mask: np.ndarray) -> np.ndarray:
    """The pixels of ``mask`` that lie in at least one 2×2 block of set pixels (a
    morphological opening by the 2×2 square)."""
    block = np.zeros(np.add(mask.shape, 1), bool)
    block[1:-1, 1:-1] = mask[:-1, :-1] & mask[1:, :-1] & mask[:-1, 1:] & mask[1:, 1:]
    return block[:-1, :-1] | block[1:, :-1] | block[:-1, 1:] | block[1:, 1:]


def _window_flow_cost(centre1, centre2, x, search_radius: int, device: str):
    """Windowed flow residual |I1(p) − I2(p + (u, v))| (h, w) of the unknowns x (vec4
    (h, w) device array), a device array."""
    from lfsf.kernels import search

    wp = _device.warp()
    h, w = centre1.shape
    zero = wp.zeros(1, dtype=wp.vec2, device=device)
    return _windowed_cost(search.flow_cost, [centre1, centre2, zero, x], 1, (h, w), search_radius, device)[0]


def _fuse_flow(x, centre1, centre2, found_u, found_v, params: Params, device: str, hidden) -> None:
    """Per pixel, keep the flow of x (the unknowns, a vec4 (h, w) device array, fused in
    place) or take the searched one (``found_u``, ``found_v``: float (h, w) device
    arrays), whichever matches better; keep it wherever ``hidden`` (float (h, w), > 0.5)
    says the point is hidden at t2, and where the flow so far takes it out of the image.
    There no match is the point's own: the search finds the occluder or whatever matches
    by chance, which then matches better than the true flow and moves the point with its
    occluder, where the geometric test of the later warps no longer sees it hidden (or,
    for a point leaving the image, with a flow of whatever it matched)."""
    from lfsf.kernels import fusion

    wp = _device.warp()
    shape = x.shape
    cand = wp.empty_like(x)
    _device.launch_rows(fusion.with_plane, dim=shape, inputs=[x, 2, found_u], outputs=[cand], device=device)
    _device.launch_rows(fusion.with_plane, dim=shape, inputs=[cand, 3, found_v], outputs=[cand], device=device)
    r = params.search_radius
    new = _window_flow_cost(centre1, centre2, cand, r, device)
    cur = _window_flow_cost(centre1, centre2, x, r, device)
    # kept also where the flow so far takes the point out of the image: no cost tells
    # anything there, and whatever the search found inside is another point
    keep = wp.empty(shape, dtype=float, device=device)
    _device.launch_rows(fusion.hidden_or_leaving, dim=shape,
                        inputs=[hidden, x],
                        outputs=[keep], device=device)
    _device.launch_rows(fusion.take_better, dim=shape, inputs=[cand, new, cur, FUSION_MARGIN, keep, 1, 2, 2],
                        outputs=[x], device=device)


def _match_floor(centre1) -> float:
    """The block cost (:func:`_surface_block_cost`) at or below which a point's flow
    is trusted: ``SURFACE_FIT_GOOD`` × the standard deviation of the t1 centre view
    ``centre1`` (a float (h, w) device array)."""
    return SURFACE_FIT_GOOD * float(np.std(centre1.numpy()))


def _surface_block_cost(centre1, centre2, x, params: Params, device: str, out=None):
    """|I1 − I2| of the centre views over the ``search_radius`` window's pixels of each
    pixel's own surface (δ1 within ``median_tolerance``), moved as a block by the
    pixel's flow in x (the unknowns, a vec4 (h, w) device array)
    (:func:`lfsf.kernels.search.surface_block_cost`): into ``out``, or a new float
    (h, w) device array, returned."""
    from lfsf.kernels import search

    if out is None:
        out = _device.warp().empty(x.shape, dtype=float, device=device)
    _device.launch_rows(search.surface_block_cost, dim=x.shape,
                        inputs=[centre1, centre2, x, params.search_radius, params.median_tolerance],
                        outputs=[out], device=device)
    return out


def _unmatched(centre1, centre2, x, params: Params, device: str, floor: float | None = None):
    """The points of x (the unknowns, a vec4 (h, w) device array) whose flow finds no
    match at t2, and of those the ones whose flow is lost: two new float (h, w) device
    arrays, 1 where so, else 0. Both by the block residual of the centre views over
    the point's own surface (:func:`_surface_block_cost`), above UNMATCHED_MEDIAN times
    its median over the image (sensor noise raises every residual) and:

    * no match: above ``floor`` (:func:`_match_floor` of ``centre1``, the surface fit's
      trust floor; None: computed here). Such a point is hidden at t2 and its flow went
      elsewhere, or its flow is off; either way its t2 samples, read at p + (u, v), show
      another point, and δ2 is that point's disparity;
    * lost: above what a flow UNMATCHED_SLOPE px off would leave there, that many times
      the 3 × 3 mean of |∇I1| (:func:`lfsf.kernels.search.cost_above`). Its flow is
      further off than the warps can pull it back, or the point is hidden at t2 and
      its flow found another point. Not where p + (u, v) lies within ``search_radius``
      px of the image's edge or beyond, where the residual's terms leave the image
      (its surface's mean motion would not extrapolate a rotation or a zoom there).

    The estimator gives the first δ2 from their surface and the second their surface's
    motion too (:meth:`lfsf.solver.LevelSolver.fill_hidden`)."""
    from lfsf.kernels import search

    wp = _device.warp()
    cost = _surface_block_cost(centre1, centre2, x, params, device)
    if floor is None:
        floor = _match_floor(centre1)
    noise = UNMATCHED_MEDIAN * float(np.median(cost.numpy()))
    no_match = wp.empty(x.shape, dtype=float, device=device)
    _device.launch_rows(search.cost_above, dim=x.shape,
                        inputs=[cost, centre1, 0.0, max(float(floor), noise), x, -1.0], outputs=[no_match],
                        device=device)
    lost = wp.empty(x.shape, dtype=float, device=device)
    _device.launch_rows(search.cost_above, dim=x.shape,
                        inputs=[cost, centre1, UNMATCHED_SLOPE, noise, x, float(params.search_radius)],
                        outputs=[lost], device=device)
    return no_match, lost


def _fit_surface_motion(x, centre1, centre2, samples2, phis, hidden, params: Params, device: str,
                        floor: float | None = None) -> None:
    """Per pixel, keep the flow and δ2 of x (the unknowns, a vec4 (h, w) device array,
    fused in place) or take those of its surface's motion fitted from the neighbours
    whose match is trusted (:func:`lfsf.kernels.occlusion.surface_motion_fit`), whichever
    matches better by ``FUSION_MARGIN``: the flow by the centre views (``centre1``,
    ``centre2``), moved as a block over the window's pixels of p's own surface
    (:func:`lfsf.kernels.search.surface_block_cost`, the ``search_radius`` window,
    ``median_tolerance``); then δ2 at the flow so chosen by the t2 samples
    (``samples2``, (S, h, w), at ``phis``; the plane sweep's windowed cost with the view
    z-buffers). Never where ``hidden`` (float (h, w) device array, > 0.5: the point has
    no match at t2).
    The coarse levels blur a surface's rim into its neighbour's motion; where the
    neighbour is the farther one, the rim's data then also finds the farther surface's
    disparity at t2, and the warps cannot pull the pair back (a plane receding by 20 %:
    its right rim, 2–3 px, moved with the backdrop). The estimator runs it on the
    finest level before its last warp, which refines what it carried over, and at the
    end (``Params.surface_fit``). ``floor``: :func:`_match_floor` of ``centre1`` where the
    caller has it (None: computed here)."""
    from lfsf.kernels import fusion, occlusion

    wp = _device.warp()
    shape = x.shape
    stride = max(1, int(round(shape[1] / SURFACE_FIT_WIDTH)))
    if floor is None:
        floor = _match_floor(centre1)
    fit = wp.empty_like(x)
    cur = wp.empty(shape, dtype=float, device=device)
    new = wp.empty(shape, dtype=float, device=device)
    untrusted = wp.empty(shape, dtype=float, device=device)
    fitted2 = wp.empty(shape, dtype=float, device=device)

    for _ in range(SURFACE_FIT_PASSES):
        _surface_block_cost(centre1, centre2, x, params, device, cur)
        # no source: a poor match, or a point hidden at t2 (its flow is the fill's)
        _device.launch_rows(fusion.either_above, dim=shape, inputs=[cur, floor, hidden, 0.5], outputs=[untrusted],
                            device=device)
        _device.launch_rows(occlusion.surface_motion_fit, dim=shape,
                            inputs=[x, untrusted, SURFACE_FIT_SIGMA, params.hidden_fill_depth, SURFACE_FIT_RADIUS,
                                    stride, SURFACE_FIT_RIDGE],
                            outputs=[fit], device=device)
        _surface_block_cost(centre1, centre2, fit, params, device, new)
        # the flow by the centre views; then δ2, at the flow now taken, by the t2 samples
        # (as the plane sweep's δ2 is fused): where the flow alone moved, a rim's δ2 of
        # the farther surface no longer matches; where it did not, δ2 keeps its value
        _device.launch_rows(fusion.take_better, dim=shape, inputs=[fit, new, cur, FUSION_MARGIN, hidden, 1, 2, 2],
                            outputs=[x], device=device)
        _device.launch_rows(fusion.unknown_plane, dim=shape, inputs=[fit, 1], outputs=[fitted2], device=device)
        _take_better_disparity(x, 1, samples2, phis, fitted2, params, device, hidden)


def _fit_solver_surfaces(solver, centres, searched_hidden, params: Params, device: str,
                         floor: float | None = None) -> None:
    """:func:`_fit_surface_motion` on a level solver's unknowns, with the level's centre
    views (``centres``, (2, h, w)) and their ``floor`` (:func:`_match_floor`; None:
    computed there); never where the point is hidden at t2, by the solver's last test
    (``hidden2``, after the fill also its ``FILL_MARGIN`` test) or by the searches'
    (``searched_hidden``, float (h, w), or None)."""
    from lfsf.kernels import fusion

    wp = _device.warp()
    shape = solver.x.shape
    hidden = wp.empty(shape, dtype=float, device=device)
    _device.launch_rows(fusion.either_above, dim=shape,
                        inputs=[solver.hidden2, 0.5, solver.hidden2 if searched_hidden is None else searched_hidden, 0.5],
                        outputs=[hidden], device=device)
    _fit_surface_motion(solver.x, centres[0], centres[1], solver.samples2, solver.phis, hidden, params, device,
                        floor)


def _relabel_outlines(solver, centres, params: Params, device: str, floor: float) -> None:
    """Give an outline pixel the state (δ1, δ2, u, v) of a neighbour on the other side of
    its depth edge where that explains its t1 samples and the centre views better
    (:func:`lfsf.kernels.fusion.take_other_surface`, by ``FUSION_MARGIN`` on both).

    A pixel of a surface's outline whose flow went with the neighbouring surface's is
    dragged by the cross-time rows (ρ3) to that surface's depth too, and the pair (δ1,
    flow) of the wrong surface then holds through the warps; the windowed fusions judge
    such a pixel mostly by its neighbours, which are right. Here each of the
    (2·RELABEL_REACH + 1)² − 1 neighbours' states, moved as a whole map, is judged at
    the pixel by the t1 samples (best half, ``search_radius`` windows, the plane sweep's
    cost) and by the flow residual of the centre views (likewise windowed). A state that
    puts the pixel behind its own (a lower δ1) must also explain better the t1 samples
    that each map's view z-buffers leave visible: the best half lets a nearer surface's
    samples, which cover a farther state's point in part of the views, speak for that
    state, and where the pixel is the nearer surface's own they show its colour (the top
    row of `indep-big_flow`'s card, in weak texture and with a flow 0.7 px off, took the
    backdrop's state: δ1 MSE 13.8× stereo only's; docs/accuracy.md); with
    ``Params.visibility`` only, as the estimator leaves it (off for samples on one side of
    the centre, the two-view case: 1.003–1.012× on δ1 with the test). Never where the
    point is hidden at t2 (the occluder then matches better than the point's own flow),
    nor where the pixel's flow matches (the flow residual at most RELABEL_FLOOR ×
    ``floor``): a stereo pair (t1 = t2), whose zero flow matches everywhere, is left as it
    is, and so the stereo-only special case. ``centres``: the level's (2, h, w) centre
    views; ``floor``: :func:`_match_floor` of the t1 one."""
    from lfsf.kernels import fusion, search

    wp = _device.warp()
    x = solver.x
    shape = x.shape
    r = params.search_radius
    reach = RELABEL_REACH
    c1, c2 = centres[0], centres[1]
    hidden = solver.find_hidden_at(x)
    # each state map's t1 cost and flow residual (t1, flow), over the shiftable windows
    current = wp.empty((3, *shape), dtype=float, device=device)
    smooth = wp.empty_like(current)
    everywhere = wp.full(shape, 1.0, dtype=float, device=device)
    margin, seen = params.occlusion_margin, int(params.visibility)
    nothing = wp.empty((1, 1, 1), dtype=float, device=device)  # (no z-buffers read without seen_too)
    _device.launch_rows(search.state_costs, dim=shape,
                        inputs=[solver.samples1, solver.phis, c1, c2, x, everywhere, nothing, 0, 0, margin, 0],
                        outputs=[current], device=device)
    _best_windows(current, r, device, smooth)
    t1_cur, flow_cur = current[0], current[1]
    # the candidates' costs only where a pixel may take one (a few per cent of them, at
    # outlines between surfaces that move apart) and within its windows' reach
    active = wp.empty(shape, dtype=float, device=device)
    _device.launch_rows(search.relabel_active, dim=shape,
                        inputs=[x, hidden, flow_cur, RELABEL_FLOOR * floor, RELABEL_DEPTH_GAP, RELABEL_FLOW_GAP, reach],
                        outputs=[active], device=device)
    support = wp.empty(shape, dtype=float, device=device)
    _device.launch_rows(search.dilated, dim=shape, inputs=[active, 2 * r], outputs=[support], device=device)
    costs = wp.empty_like(current)
    # and, there too, the t1 cost over the samples that the view z-buffers of δ1 leave
    # visible (seen); a candidate map, x moved as a whole, reads them moved. Without
    # Params.visibility (or where the estimator turned it off, as for samples on one side
    # of the centre) no z-buffers: the best half alone, as before
    zbuf, seen_cur = nothing, current[2]
    if seen:
        zbuf = _view_zbuffer(x, 0, False, solver.phis, device)
        _device.launch_rows(search.state_costs, dim=shape,
                            inputs=[solver.samples1, solver.phis, c1, c2, x, support, zbuf, 0, 0, margin, 1],
                            outputs=[costs], device=device)
        _best_windows(costs, r, device, smooth)
        seen_cur = wp.clone(costs[2])
    best = wp.full(shape, float("inf"), dtype=float, device=device)
    out = wp.clone(x)
    cand = wp.empty_like(x)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            if dy == 0 and dx == 0:
                continue
            _device.launch_rows(fusion.shifted, dim=shape, inputs=[x, dy, dx], outputs=[cand], device=device)
            _device.launch_rows(search.state_costs, dim=shape,
                                inputs=[solver.samples1, solver.phis, c1, c2, cand, support, zbuf, dy, dx, margin,
                                        seen],
                                outputs=[costs], device=device)
            _best_windows(costs, r, device, smooth)
            _device.launch_rows(fusion.take_other_surface, dim=shape,
                                inputs=[x, cand, costs[1], flow_cur, costs[0], t1_cur, costs[2], seen_cur, hidden,
                                        RELABEL_FLOOR * floor, FUSION_MARGIN, RELABEL_DEPTH_GAP, RELABEL_FLOW_GAP,
                                        seen],
                                outputs=[best, out], device=device)
    wp.copy(x, out)


def _take_better_disparity(x, component: int, samples, phis, candidate, params: Params, device: str,
                           hidden=None, fusion_margin: float = FUSION_MARGIN) -> None:
    """Per pixel, keep δ1 (``component`` 0, judged by the t1 ``samples`` at p) or δ2
    (1, by the t2 samples at p + (u, v)) of x (the unknowns, a vec4 (h, w) device array,
    fused in place), or take ``candidate`` (float (h, w) device array) where its cost is
    below ``fusion_margin`` times the current one, and not where ``hidden`` (float (h,
    w), > 0.5; None: anywhere). With ``params.visibility`` both values are judged by the
    samples that the candidate map's view z-buffers leave visible (the same samples for
    both), else by the best half (:func:`_window_cost`)."""
    from lfsf.kernels import fusion

    wp = _device.warp()
    shape = x.shape
    at_t2 = component == 1
    offset = x if at_t2 else wp.zeros(shape, dtype=wp.vec4, device=device)
    cand = wp.empty_like(x)
    _device.launch_rows(fusion.with_plane, dim=shape, inputs=[x, component, candidate], outputs=[cand], device=device)
    zbuf = _view_zbuffer(cand, component, at_t2, phis, device) if params.visibility else None
    current = wp.empty(shape, dtype=float, device=device)
    _device.launch_rows(fusion.unknown_plane, dim=shape, inputs=[x, component], outputs=[current], device=device)
    r, margin = params.search_radius, params.occlusion_margin
    cur = _window_cost(samples, phis, current, offset, r, device, zbuf, margin)
    new = _window_cost(samples, phis, candidate, offset, r, device, zbuf, margin)
    _device.launch_rows(fusion.take_better, dim=shape,
                        inputs=[cand, new, cur, fusion_margin, new if hidden is None else hidden,
                                int(hidden is not None), component, 1],
                        outputs=[x], device=device)


def _fuse_disparities(x, s1, s2, phis, found1, found2, params: Params, device: str, keep=None,
                      fusion_margin: float = FUSION_MARGIN, nearby: bool = False) -> None:
    """Per pixel, keep δ1 (δ2) of x (the unknowns, a vec4 (h, w) device array, fused in
    place) or take the searched one (``found1``, ``found2``: float (h, w) device arrays,
    each in its own time's frame: δ2's is read at p + (u, v)), whichever matches better
    (:func:`_take_better_disparity`, by ``fusion_margin``); keep both wherever ``keep``
    (float (h, w) device array, or None) is above 0.5. With ``nearby``, a searched value
    is taken only where a pixel within LATE_SEARCH_REACH px holds one of the same
    unknown within LATE_SEARCH_DEPTH of it (:func:`lfsf.kernels.fusion.depth_nearby`)."""
    from lfsf.kernels import fusion

    wp = _device.warp()

    def kept(component: int, candidate):
        if not nearby:
            return keep
        out = wp.empty(x.shape, dtype=float, device=device)
        _device.launch_rows(fusion.depth_nearby, dim=x.shape,
                            inputs=[x, component, candidate, LATE_SEARCH_REACH, LATE_SEARCH_DEPTH,
                                    candidate if keep is None else keep, int(keep is not None)],
                            outputs=[out], device=device)
        return out

    # δ1: the searched map in the centre view at t1
    _take_better_disparity(x, 0, s1, phis, found1, params, device, kept(0, found1), fusion_margin)
    # δ2: the searched map of t2's frame read where the point moves, p + (u, v)
    cand2 = wp.empty(x.shape, dtype=float, device=device)
    _device.launch_rows(fusion.sample_at_flow, dim=x.shape, inputs=[found2, x], outputs=[cand2], device=device)
    _take_better_disparity(x, 1, s2, phis, cand2, params, device, kept(1, cand2), fusion_margin)


#: What :func:`estimate_scene_flow` takes for a light field.
LightFieldLike = Union[LightField, np.ndarray, str, os.PathLike]


def estimate_scene_flow(
    lf1: LightFieldLike,
    lf2: LightFieldLike,
    params: Params | str | None = None,
    *,
    device: str | None = None,
    progress: ProgressFn | None = None,
    init: SceneFlow | Mapping[str, np.ndarray] | None = None,
) -> SceneFlow:
    """Estimate scene flow between two light fields (Heber & Pock, GCPR 2014).

    Parameters
    ----------
    lf1, lf2 : LightField, array [a, b, y, x] / [a, b, y, x, c], or path
        Light fields at t1 and t2, same view grid and size (a path is read with
        :func:`lfsf.read_lightfield`); colour is matched as luma, the t1 centre view's
        colours shape δ1's diffusion tensor (``Params.colour_tensor``), and at the end
        they place δ1's and δ2's depth edges (``Params.colour_median_radius``). The
        disparities need views where the samples land (:meth:`lfsf.Params.grid_radius`):
        the presets' need 2 rows and 2 columns of views; a rig of one row (column) takes
        ``circles=2, samples=(1, 2)``; flow only, ``circles=1``, needs one view.
        Light fields whose joint intensity range spans less than 0.2 or more than 2
        are stretched to [0, 1] first (e.g. 12-bit data stored in 16 bits, or counts
        given as floats; float views far outside [0, 1] are warned about); the others
        are used as they are. Where t2 was captured at
        another exposure, its views are first matched to t1's by a gain and an offset
        (``Params.match_exposure``; the progress names them), or by a tone curve
        (``Params.tone_curve``, off; the progress tells where the line leaves a bow).
    params : Params or str, optional
        Settings, or a preset's name (``"fast"``: ``Params.preset("fast")``; default
        ``"paper"``).
    device : str, optional
        ``cpu`` or ``cuda:N`` (default: :func:`lfsf.device.resolve_device`).
    progress : callable, optional
        Called with a line of text at each level and warp, and with a :class:`Note`
        (a ``str``) for each decision about the input: an exposure matched or refused,
        the views' gains matched, the view z-buffers off.
    init : SceneFlow or dict, optional
        A starting estimate (``disp1``, ``disp2``, ``u``, ``v``, (H, W) maps of the t1
        centre view), e.g. :func:`predict_next` of the previous pair of a sequence. The
        coarsest level run (all levels, or the finest ``params.warm_levels``) starts from
        it instead of from zero; the searches still fuse in where they match better. With
        all levels (``warm_levels = 0``, the default) the coarse levels rework most of
        it: the exact ground truth as ``init`` moved the errors of δ1, δ2 and the flow
        by −46 % to +71 % against no ``init`` (`paper`, `random-2`, `large_motion`,
        160×120, `fast`), while with ``warm_levels = 1`` δ2's MSE fell 2× and 8× on
        `paper` and `large_motion` (+5 % on `random-2`) and the flow's EPE by up to 2.7×.
        Set ``warm_levels`` where ``init`` is close (README, Warm starts).

    Returns
    -------
    SceneFlow
        δ1, δ2, u, v of the centre view at t1 (``help(lfsf)``, MODEL.md §1).

    Warns
    -----
    LfsfWarning
        (``lfsf.LfsfWarning``, a UserWarning) Where a light field's float views lie far
        outside [0, 1] (what is done with them), and where t1's or t2's views look laid out
        otherwise than ``views[a, b, y, x]``: two axes swapped, or one of the grid's
        reversed (:mod:`lfsf.orientation`). With :data:`WARNINGS_TO_PROGRESS` set they go
        to ``progress`` as :class:`Warned` lines instead (``lfsf batch``).

    Notes
    -----
    Special cases come from the same code: ``estimate_scene_flow(lf, lf)`` is stereo.
    With the ``paper`` preset the flow comes out within 0.01 px of zero and δ2 within
    0.01 of δ1 but near depth edges, where a sample's rows drop out at one time and not
    the other (scene ``paper`` at 160×120, 9×9 views, fiftieth session: flows above
    0.01 px at 0.016 % of the pixels, largest 0.027 px; |δ2 − δ1| above 0.01 nowhere,
    largest 0.0026). ``fast`` (3 warps of 30 iterations against 5 of 100) stops further
    from that fixed point: median flow 0.001 px, above 0.01 px at 2.4 % of the pixels,
    largest 0.28 px; |δ2 − δ1| above 0.01 at 0.09 %, largest 0.30. On real views it stops
    further still: HCI antinous at 256×256 (``lf.downsample(2)``), 8-px border, ``fast``:
    median flow 0.0025 px, above 0.01 px at 14 %, largest 0.53 px; |δ2 − δ1| above 0.01 at
    2.5 %, largest 1.38 (``paper``: 0.0002 px, 0.03 %, 0.25 px; 0.02 %, 0.72). On colour
    light fields δ1's tensor is the colour one and δ2's the luma's, which adds a little
    (`random-5` in colour at 96×72, `fast`: largest flow 0.17 px against 0.11 with
    ``colour_tensor`` off; fifty-first session). ``circles=1`` is optical flow of the
    centre views alone, ``circles=2, samples=(1, 1)`` is two-view stereo plus flow.

    References
    ----------
    S. Heber and T. Pock, "Scene Flow Estimation from Light Fields via the
    Preconditioned Primal-Dual Algorithm", GCPR 2014.
    """
    # The light fields handed over in a list that the estimate empties: where the caller
    # holds them no more, they are freed once sampled (a frame that kept them as its own
    # arguments, as a wrapper's would, kept 195 MB alive at 640×480 for the whole run).
    handed = [lf1, lf2]
    del lf1, lf2
    with interrupts_kept():
        return _estimate_scene_flow(handed, params, device=device, progress=progress, init=init)


def _estimate_scene_flow(handed: list[LightFieldLike], params: Params | str | None, *, device: str | None,
                         progress: ProgressFn | None, init: SceneFlow | Mapping[str, np.ndarray] | None) -> SceneFlow:
    """:func:`estimate_scene_flow` of the two light fields in ``handed`` (taken out of it)."""
    lf1, lf2 = handed.pop(0), handed.pop(0)
    from lfsf.kernels import fusion, pyramid
    from lfsf.kernels import gains as gain_kernels
    from lfsf.solver import LevelSolver

    wp = _device.warp()
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name):
        nonlocal clock
        if not _device.is_cpu(dev):
            wp.synchronize_device(dev)
        now = time.perf_counter()
        timings[name] = timings.get(name, 0.0) + now - clock
        clock = now

    if progress is not None and not callable(progress):       # (found only after the first level)
        raise ValueError(f"progress must be a callable taking a line, got {type(progress).__name__}")
    say = progress or (lambda _msg: None)

    def note(message: str) -> None:
        say(Note(message))

    if params is None or isinstance(params, str):
        params = Params.preset("paper" if params is None else params)
    if not isinstance(params, Params):
        raise ValueError(f"params must be an lfsf.Params or a preset's name, got {type(params).__name__}")
    lf1 = _as_lightfield(lf1, "light field 1")
    lf2 = _as_lightfield(lf2, "light field 2")
    # each light field's value range, taken once: the pair's check and the intensity stretch read it
    ranges = [(float(np.min(lf.views)), float(np.max(lf.views))) for lf in (lf1, lf2)]
    for lf, (lo, hi) in zip((lf1, lf2), ranges):
        if not (math.isfinite(lo) and math.isfinite(hi)):  # (written into its views after it was made)
            _refuse_non_finite(lf.views, lf.source)
    _check_pair_brightest(lf1, lf2, [hi for _lo, hi in ranges])
    for lf, (lo, hi) in zip((lf1, lf2), ranges):
        # (the maps had come out as anything, without a word; the centre view first: one look for most)
        if lo == hi or (not np.ptp(lf.views[lf.grid[0] // 2, lf.grid[1] // 2]).any()
                        and not np.ptp(lf.views, axis=(2, 3)).any()):
            what = f"every value of every view is {lo:g}" if lo == hi else "every view is of one value"
            raise ValueError(f"{lf.source}: {what}: a blank light field (a black frame, a lens cap, a raw image of "
                             "nothing, a flat field), with nothing to match")
    dev = _device.resolve_device(device)
    rows, cols = lf1.grid
    height, width = lf1.height, lf1.width
    if min(height, width) < 8:
        from lfsf.io import _stack_hint

        # (an (N, H, W, 3) stack of colour views reads as a grid of N × H grey views 3 px wide)
        raise ValueError(f"{lf1.source}: views of {width}×{height} pixels are too small (at least 8×8)"
                         + (_stack_hint(lf1.views.shape) if not lf1.is_colour else ""))

    rim = _rim_radius(lf1)
    phis, radius = (params if rim is None else params.replace(radius=min(params.radius, rim))).sample_offsets(
        (rows, cols))
    grid_radius = params.grid_radius((rows, cols))
    if rim is not None and params.circles > 1 and rim < grid_radius:
        # (only where the rims, not the grid, set R: the grid's own limit has its note below)
        note(f"sampling radius R = {radius:g} {_view_steps(radius)}, not {params.radius:g}: the views were decoded from a "
             f"lenslet image, {lf1.meta['lens_views']} across a lens, and those further out lie near the "
             "micro-images' rims, where the neighbouring lenses mix in (RIM_FRACTION)")
    if params.circles > 1 and radius <= 0:
        flow = ("the flow of the centre views alone: the flow preset (Params.preset('flow'), --preset flow; "
                "circles = 1, samples = [1])")
        if rows == cols == 1:
            raise ValueError(f"{lf1.source}: a single view leaves no room for the sampling circles (M = "
                             f"{params.circles}): the disparities need two views or more; {flow}")
        axis = "column" if rows > cols else "row"
        raise ValueError(f"{lf1.source}: {_a(rows)} {rows}×{cols} grid of views leaves no room for the sampling circles "
                         f"(M = {params.circles}, N = {list(params.samples)}): samples off the grid's {axis} need "
                         f"views beside it; on a one-{axis} rig, sample along it with circles = 2 and samples = "
                         "[1, 2] (the views R steps either side of the centre; params.replace(circles=2, "
                         f"samples=(1, 2)) in Python, a --config FILE.toml for lfsf run), or {flow}")
    dark = (_dark_views(lf1, lf2, params.dark_view_fraction, min(lo for lo, _ in ranges))
            if params.circles > 1 and params.dark_view_fraction > 0 else None)
    darkened = False  # (R lowered to keep off dark views: the grid's note below is not of this R)
    if dark is not None and dark.flat[sampled_views(phis, rows, cols)].any():
        listed = [f"({a}, {b})" for a, b in zip(*np.nonzero(dark))]
        count = int(dark.sum())
        what = (f"{count} of the {rows}×{cols} views {'is' if count == 1 else 'are'} dark (mean brightness under "
                f"{params.dark_view_fraction:g} of the views' median, at t1 or t2; views (row, column) from 0, as "
                f"LightField.view takes them: {', '.join(listed[:8])}{', …' if count > 8 else ''})")
        off = None
        if dark.flat[sampled_views(np.zeros((1, 2), np.float32), rows, cols)].any():
            note(f"{what}, among them the centre view{'s' if rows % 2 == 0 or cols % 2 == 0 else ''}, which every "
                 "sample is compared with: the estimate will be poor (a view of nothing matches nothing)")
        else:
            off = _radius_off_dark_views(params, (rows, cols), dark, radius)
            if off is None:
                note(f"{what}, and the samples read some at "
                     + (f"R = {radius:g}" if radius <= 1.0 else f"every radius from R = {radius:g} down to 1")
                     + ": the disparities may suffer (a view of nothing matches nothing; dark_view_fraction)")
        if off is not None:
            asked = radius
            phis, radius = params.replace(radius=off).sample_offsets((rows, cols))
            darkened = True
            limit = ("the micro-images' rims allow" if rim is not None and rim <= grid_radius
                     else f"the {rows}×{cols} grid allows")
            note(f"sampling radius R = {radius:g} {_view_steps(radius)}, not {params.radius:g}"
                 + (f" (nor {asked:g}, all {limit})" if asked < params.radius else "")
                 + f": {what}, and the samples keep off them (dark_view_fraction = 0 reads them all the same)")
    cut = grid_radius < params.radius and (rim is None or grid_radius <= rim) and not darkened  # (R set by the grid)
    if params.circles > 1 and (cut or radius < 1.0):
        note(f"sampling radius R = {radius:g} {_view_steps(radius)}"
             + (f", not {params.radius:g} (all the {rows}×{cols} grid allows for these samples)" if cut else "")
             + (": the side samples see little parallax, and δ is less certain than with R ≥ 1"
                if radius < 1.0 else ""))
    if params.circles > 1 and not _IN_PILOT.get():
        # a transposed array or a grid numbered the other way reads without error and gives
        # disparities of no meaning: said, of each light field
        from lfsf.orientation import layout_warning

        for lf in (lf1,) if lf2.views is lf1.views else (lf1, lf2):
            told = layout_warning(lf.views, lf.source, params.disparity_range)
            if told:
                _warn(told, say)
    lap("checks")  # (with the input's checks above)
    # every kernel module compiled (or read from Warp's cache) now, several at once, rather
    # than one at a time at each module's first launch
    compiled = load_kernels(dev, say=progress)
    if compiled:
        say(compiled)
    lap("kernels")
    requested = params
    if params.visibility and one_sided(phis):
        params = params.replace(visibility=False)
        note("view z-buffers off: the side samples lie on one side of the centre (Params.visibility)")
    elif params.visibility and radius < VISIBILITY_MIN_RADIUS:
        params = params.replace(visibility=False)
        if params.circles > 1:  # (flow only has no side views to buffer: nothing to say)
            note(f"view z-buffers off at R = {radius:g} (below {VISIBILITY_MIN_RADIUS:g}: Params.visibility)")
    n_samples = len(phis)
    weights = data_weights(params, n_samples)
    wp_phis = wp.array(phis, dtype=wp.vec2, device=dev)
    wp_weights = wp.array(weights, dtype=wp.vec3, device=dev)

    # sub-aperture images at the sample offsets, both times: (S, H, W) each
    offset, stretch = _intensity_stretch(lf1, lf2, ranges)
    for lf, (lo, hi) in zip((lf1, lf2), ranges):
        _warn_out_of_unit_range(lf.source, lo, hi, stretch != 1.0, say, lf.views)

    def stretched(grey: np.ndarray) -> np.ndarray:
        if stretch == 1.0:
            return grey
        if stretch > float(np.finfo(np.float32).max):  # a span below 2.9e-39: 1/span overflows float32
            return ((grey - np.float32(offset)) / np.float32(1.0 / stretch)).astype(np.float32)
        return (grey - np.float32(offset)) * np.float32(stretch)

    exposure_fit = None  # (the change of exposure t2 is matched by, where one is)
    source = lf1.source   # (for the messages: the light fields themselves are let go below)

    def unmatched_exposure(message: str) -> None:
        """A change of brightness left unmatched: a note, and a warning where it is as
        large as UNMATCHED_BRIGHTNESS_WARNING (t2 at 0.1 of t1's exposure on 48×36 views:
        δ2 MSE 1.9, EPE 3.1, said only in the progress that library callers do not see)."""
        if abs(brighter) > UNMATCHED_BRIGHTNESS_WARNING and not _IN_PILOT.get():
            _warn(f"{source}: {message}; the flow and δ2 will be poor where the exposure or the light changed",
                  say)
        else:
            note(message)

    large = max(height, width) >= EXPOSURE_MIN_SIZE
    brighter = 0.0  # (small or short views: how far t2's mean brightness lies from t1's, as a share)
    if params.match_exposure and not (large and min(height, width) >= EXPOSURE_MIN_SHORT):
        means = [float(np.mean(centre_view(lf.views))) for lf in (lf1, lf2)]
        brighter = means[1] / means[0] - 1 if means[0] > 0 else 0.0
    if params.match_exposure and min(height, width) >= EXPOSURE_MIN_SHORT and (
            large or abs(brighter) > SMALL_VIEWS_BRIGHTNESS):
        # the grey centre views alone (luma is linear: the luma of the centre is the centre of the luma)
        grey_centres = [stretched(luma(centre_view(lf.views)) if lf.is_colour else centre_view(lf.views))
                        for lf in (lf1, lf2)]
        if not np.array_equal(*grey_centres):
            fitted = _exposure_change(*grey_centres, dev, note=note)
            gain, shift, change = fitted.gain, fitted.shift, fitted.change
            told, bow = "", ""  # (the global match's line, and its advice of a tone curve)
            if change > (EXPOSURE_CHANGE if large else SMALL_VIEWS_CHANGE):
                exposure_fit = fitted if params.tone_curve else fitted._replace(curve=None)
                line = f"I ↦ {gain:.4f}·I {shift:+.4f}"
                if exposure_fit.curve is not None:
                    how = (f"a tone curve of {len(fitted.curve[0])} knots (it moved the intensities by up to "
                           f"{100 * change:.1f} % of their range; the line {line} left some "
                           f"{100 * fitted.departure:.1f} % off)")
                else:
                    how = f"{line} (it moved the intensities by up to {100 * change:.1f} % of their range)"
                    if fitted.curve is not None:
                        bow = (f"; the line leaves some intensities {100 * fitted.departure:.1f} % of the range "
                               "off in a bow, as a tone curve would (another gamma, an auto-tone camera): "
                               "tone_curve = true (params.replace(tone_curve=True)) matches it by a curve")
                told = f"exposure: t2 matched to t1 by {how}"  # (said below, with the local field's line)
            elif not large:
                unmatched_exposure(f"exposure: not matched, though t2's mean brightness differs from t1's by "
                                   f"{100 * brighter:+.1f} %: on views of {width}×{height} the fit found a change of "
                                   f"{100 * change:.1f} % of the range, and views under {EXPOSURE_MIN_SIZE} px need "
                                   f"{100 * SMALL_VIEWS_CHANGE:g} %")
            light = None
            if fitted.pilot is not None and large:  # (smaller views: their pilot runs for a global change alone)
                matched = grey_centres[1] if exposure_fit is None else exposure_fit.apply(grey_centres[1])
                light = _local_light(grey_centres[0], matched, fitted.pilot)
            if told:
                # (a change over part of the view bows the line too: then the curve is one reading of two)
                note(told + (bow if light is None or not bow else
                             bow + ", or it is the change over part of the view matched below"))
            if light is not None:
                field, _factor, share, largest = light
                brighter_at_t2 = float(np.mean(field[np.abs(field) >= 0.5 * float(np.max(np.abs(field)))])) < 0
                exposure_fit = (exposure_fit or Exposure(1.0, 0.0, 0.0))._replace(light=light[:2])
                note(f"exposure: part of the view is {'brighter' if brighter_at_t2 else 'darker'} at t2 than at t1 "
                     f"({'a glare, a light turned on' if brighter_at_t2 else 'a shadow, a light turned off'}?): "
                     f"by up to {100 * largest:.0f} % of the range over {100 * share:.0f} % of the view; t2 "
                     "matched to t1 there by a smooth field"
                     + ("" if not told else " after the curve" if exposure_fit.curve is not None else " after the line")
                     + ("" if told else " (no change of exposure over the whole view)"))
        lap("exposure")
    elif params.match_exposure and abs(brighter) > SMALL_VIEWS_BRIGHTNESS:
        # views too short to fit: said, since a change of exposure then goes unmatched, and it
        # costs the flow dearly (×1.1 at 96×72 took the flow's EPE from 0.05 to 0.76)
        unmatched_exposure(f"exposure: not matched, though t2's mean brightness differs from t1's by "
                           f"{100 * brighter:+.1f} % (views of {width}×{height}; measuring a change of "
                           f"exposure needs {EXPOSURE_MIN_SHORT} px along the shorter side)")
    gains = views1 = None
    if params.view_gain_sigma > 0 and n_samples > 1 and min(height, width) >= MIN_VIEW_SIZE:
        # the views' brightness matched to the centre's, the same fields at both times: fitted
        # on the t1 views reduced by block means (on the device, where they are sampled
        # below), and only for the views the samples read
        views1 = wp.array(np.ascontiguousarray(stretched(lf1.grey().views), dtype=np.float32).reshape(
            rows * cols, height, width), dtype=float, device=dev)
        factor = reduction_factor(height, width)
        small = wp.empty((rows * cols, height // factor, width // factor), dtype=float, device=dev)
        if min(small.shape[1:]) >= 16:
            _device.launch_rows(gain_kernels.block_mean, dim=(rows * cols * small.shape[1], small.shape[2]),
                                inputs=[views1, factor], outputs=[small], device=dev)
            used = sampled_views(phis, rows, cols)
            fitted = fit_reduced_gains(small.numpy().reshape(rows, cols, *small.shape[1:]), factor,
                                       params.view_gain_sigma, dev, used=used)
            if fitted is not None:
                fitted = fitted.reshape(rows * cols, *small.shape[1:])
                # (on the reduced fields of the views sampled: the full ones only where they are used)
                change = gain_change(fitted[used], border=-(-8 // factor))
                if change > GAIN_CHANGE:
                    gains = (wp.array(fitted.astype(np.float32), dtype=float, device=dev),
                             wp.array(np.asarray(used, np.int32), dtype=wp.int32, device=dev), factor)
                    low, high = float(fitted[used].min()), float(fitted[used].max())
                    clipped = high >= np.float32(MAX_GAIN) or low <= np.float32(1.0 / MAX_GAIN)
                    note(f"view gains: each view sampled matched to the centre view's brightness (gains "
                         f"{low:.3f}–{high:.3f}, 95th percentile of the change {100 * change:.1f} %)"
                         + (f"; some reach their bound, ×{MAX_GAIN:g} or ×{1 / MAX_GAIN:g} (lfsf.gains.MAX_GAIN): "
                            "parts of those views differ from the centre by more than the gains match (strong "
                            "vignetting, a dark rim?)" if clipped else ""))
        del small
        lap("view gains")
    # the samples of both times in one stack, t1's first (as the texture split takes them)
    both = wp.empty((2 * n_samples, height, width), dtype=float, device=dev)
    for t, lf in enumerate((lf1, lf2)):
        # one grey light field at a time; the caller's views are never written
        if t == 0 and views1 is not None:
            views, views1 = views1, None
        else:
            # only the views the sampling reads (each sample's four around it, those of
            # weight 0 too), in their places of an otherwise unfilled stack: flow only,
            # the centre's four of 81, not the whole light field (its copy to the device
            # had been most of the stage)
            read = touched_views(phis, rows, cols)
            flat = lf.views.reshape(rows * cols, height, width, *lf.views.shape[4:])[read]
            grey = stretched(luma(flat) if lf.is_colour else flat)
            if t == 1 and exposure_fit is not None:
                grey = exposure_fit.apply(grey)
            if len(read) == rows * cols:
                views = wp.array(np.ascontiguousarray(grey, dtype=np.float32), dtype=float, device=dev)
            else:
                views = wp.empty((rows * cols, height, width), dtype=float, device=dev)
                if _device.is_cpu(dev):
                    views.numpy()[read] = grey  # (the device's memory itself)
                else:
                    for k, index in enumerate(read):
                        views[index].assign(np.ascontiguousarray(grey[k], dtype=np.float32))
            del grey, flat
        if gains is not None:
            fields, index, factor = gains
            _device.launch_rows(gain_kernels.apply_gains, dim=(index.shape[0] * height, width),
                                inputs=[fields, index, factor], outputs=[views], device=dev)
        sample_views(views, rows, cols, wp_phis, both[t * n_samples:(t + 1) * n_samples], dev)
        del views
    del gains
    lap("sampling")
    colour = (_centre_colour(lf1, offset, stretch)
              if (params.colour_median_radius > 0 or params.colour_tensor) and n_samples > 1 else None)
    # the light fields are not read again: where the caller no longer holds them (lfsf run
    # hands them over) their memory is free for the levels' buffers (lf: the sampling loop's
    # last; the centre views of the exposure match: slices of the views where nothing
    # stretched them, which kept the whole arrays)
    del lf1, lf2, lf
    grey_centres = matched = None
    centres = [wp.clone(both[t * n_samples]) for t in range(2)]
    texture = _normalise_contrast(_structure_texture(both, params, dev), params, dev)
    lap("texture")

    sizes = pyramid_sizes(height, width, params)
    start = _check_init(init, height, width)
    if start is not None and params.warm_levels:
        sizes = sizes[:params.warm_levels]
    # the t1 centre view's colour planes for Γ_t1 (Params.colour_tensor), on every level
    planes = (wp.array(np.ascontiguousarray(np.moveaxis(colour, -1, 0)), dtype=float, device=dev)
              if colour is not None and params.colour_tensor else None)
    levels = [(texture, _stack2(centres, dev), planes)]
    for size in sizes[1:]:
        tex, cen, col = levels[-1]
        levels.append((_downsample(tex, size, dev), _downsample(cen, size, dev),
                       None if col is None else _downsample(col, size, dev)))
    lap("pyramid")
    search = params.disparity_search and n_samples > 1
    if search:
        # the sweep runs once, on level SWEEP_LEVEL (full resolution)
        k = min(SWEEP_LEVEL, len(sizes) - 1)
        tex = levels[k][0]
        level_scale = sizes[k][1] / width
        margin = params.occlusion_margin * level_scale if params.visibility else None
        found = [wp.array(_sweep(wp.clone(tex[t * n_samples:(t + 1) * n_samples]), wp_phis, radius,
                                 params.disparity_range * level_scale, params.search_radius, dev, margin)
                          / level_scale, dtype=float, device=dev)
                 for t in (0, 1)]
        lap("search")
    flow_search = params.flow_search
    unmatched = 0.0   # (the share of pixels the flow search found no clear match for)
    if flow_search:
        flow_range = searched_flow_range(params, sizes)
        k = flow_search_level(sizes, flow_range, params.pyramid_scale)
        half = flow_search_half(flow_range, params.pyramid_scale, k, sizes[k])
        if half > MAX_FLOW_SEARCH_HALF:
            coarser = ("allow more pyramid levels (max_levels)" if params.max_levels and len(sizes) == params.max_levels
                       else f"a smaller min_size ({params.min_size}) for coarser pyramid levels")
            # (flow_range's own: a range that the views' size sets stays within reach, above)
            raise ValueError(f"flow_range {flow_range:g} px needs a block search of ±{half} px on the "
                             f"{sizes[k][1]}×{sizes[k][0]} level ({(2 * half + 1) ** 2} shifts per pixel; at most "
                             f"±{MAX_FLOW_SEARCH_HALF}): lower flow_range, or {coarser}")
        if flow_range > params.flow_range:  # (the views' size set the range, not flow_range)
            note(_shared_range_note(params, max(sizes[0]), flow_range))
        tex = levels[k][0]
        c1, c2 = wp.clone(tex[0]), wp.clone(tex[n_samples])
        forward, ambiguous = _flow_search(c1, c2, half, params.search_radius, dev, ambiguity=True)
        hidden = _hidden_matches(forward, _flow_search(c2, c1, half, params.search_radius, dev))
        # (unfused, as the ambiguous matches: where the matches are noise, FLOW_INCOHERENT_REGION)
        ambiguous |= _incoherent_regions(forward)
        unmatched = float(np.mean(ambiguous))   # (told at the end where the estimate does not match either)
        flow_found = [wp.array(np.ascontiguousarray(a, np.float32), dtype=float, device=dev)
                      for a in (forward[..., 0], forward[..., 1], hidden, ambiguous)]
        lap("search")
    say(f"{width}×{height}, {rows}×{cols} views, {n_samples} sample{'s' if n_samples != 1 else ''}"
        + (f" (R = {radius:g})" if n_samples > 1 else "")
        + f", {len(sizes)} level{'s' if len(sizes) != 1 else ''} on {dev}")

    # the unknowns: on the device between levels (x_dev, vec4), on the host (x) at the
    # start, at the end, and for flow only (whose solver holds (δ1, δ2) on the host)
    x = x_dev = coarser = None  # (coarser: the coarser level's solver)
    hidden_here = None
    for level in range(len(sizes) - 1, -1, -1):
        h, w = sizes[level]
        tex, cen, col = levels[level]
        s1 = wp.clone(tex[:n_samples])
        s2 = wp.clone(tex[n_samples:])
        solver = LevelSolver(s1, s2, wp.clone(cen[0]), wp.clone(cen[1]), wp_phis, wp_weights, params, dev,
                             level_scale=w / width, colour1=col)
        if x_dev is None:
            if x is None and start is not None:
                scales = (w / width, w / width, w / width, h / height)  # δ1, δ2 and u with the width, v with the height
                x = np.stack([_resize_map(start[..., c], (h, w), scales[c], dev) for c in range(4)], -1)
            elif x is None:
                x = np.zeros((h, w, 4), np.float32)
            x_dev = wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec4, device=dev)
        # the searches fuse into x on the device (kernels.fusion)
        if flow_search:
            found_u, found_v, found_hidden, found_ambiguous = flow_found
            search_h, search_w = found_u.shape
            # not where the point is hidden at t2: by the searches (its match is another
            # point's), or by the estimate so far (its flow comes from the regulariser)
            hidden_here = wp.empty((h, w), dtype=float, device=dev)
            _device.launch_rows(fusion.either_above, dim=(h, w),
                                inputs=[_resize_plane(found_hidden, (h, w), 1.0, dev), 0.01,
                                        solver.find_hidden_at(x_dev), 0.5],
                                outputs=[hidden_here], device=dev)
            # nor where the search's match was ambiguous (FLOW_AMBIGUITY)
            unfused = wp.empty((h, w), dtype=float, device=dev)
            _device.launch_rows(fusion.either_above, dim=(h, w),
                                inputs=[_resize_plane(found_ambiguous, (h, w), 1.0, dev), 0.5, hidden_here, 0.5],
                                outputs=[unfused], device=dev)
            _fuse_flow(x_dev, s1[0], s2[0], _resize_plane(found_u, (h, w), w / search_w, dev),
                       _resize_plane(found_v, (h, w), h / search_h, dev), params, dev, unfused)
            lap("search")
        if search:
            scale = w / width
            _fuse_disparities(x_dev, s1, s2, wp_phis, _resize_plane(found[0], (h, w), scale, dev),
                              _resize_plane(found[1], (h, w), scale, dev), params, dev)
            lap("search")
        solver.set_state(x_dev)
        x = x_dev = None
        if coarser is not None:
            # w and the disparities' TGV duals (Params.carry_duals) go on to this level on the device
            solver.take_coarse(coarser, params.carry_duals and n_samples > 1)
            coarser = None
        lap("setup")
        # each surface's motion carried to its rim (Params.surface_fit), on the finest level
        fit_surfaces = level == 0 and params.surface_fit and not solver.flow_only
        late_search = level == 0 and search and params.late_search
        # the t1 centre view's match floor (a read back to the host), read once for the
        # level by the first of its readers (the late search, the surface fits, and at the
        # end the fill's test of the unmatched points and the outlines' relabelling)
        floor = functools.cache(functools.partial(_match_floor, cen[0]))
        for k in range(params.warps):
            if level == 0 and k == params.warps - 1 and k > 0:
                if late_search:
                    # the plane sweep's maps once more (Params.late_search): through the
                    # cross-time rows a wrong flow at an outline drags δ1 and δ2 to the
                    # other surface's depth over the warps. Only where the flow does not
                    # match; elsewhere δ1 and δ2 stay the warps' own, finer than the
                    # sweep's steps (a stereo pair, t1 = t2, whose flow matches everywhere,
                    # keeps them); there ties go to the sweep (LATE_SEARCH_MARGIN), where
                    # a surface at the sweep's depth lies near (LATE_SEARCH_REACH). The
                    # last warp refines what this takes.
                    matched = wp.empty((h, w), dtype=float, device=dev)
                    _device.launch_rows(fusion.at_most, dim=(h, w),
                                        inputs=[_surface_block_cost(cen[0], cen[1], solver.x, params, dev), floor()],
                                        outputs=[matched], device=dev)
                    _fuse_disparities(solver.x, solver.samples1, solver.samples2, solver.phis, found[0], found[1],
                                      params, dev, matched, LATE_SEARCH_MARGIN, nearby=True)
                    lap("search")
                if fit_surfaces:
                    # before the last warp too, which then refines what it carried over
                    _fit_solver_surfaces(solver, cen, hidden_here, params, dev, floor())
                    lap("median")
            solver.linearise()
            lap("linearise")
            last = level == 0 and k == params.warps - 1 and params.final_iterations > 0
            solver.iterate(params.final_iterations if last else params.iterations)
            lap("iterate")
            solver.median()
            lap("median")
            say(f"level {len(sizes) - level}/{len(sizes)} ({w}×{h}), warp {k + 1}/{params.warps}")
        if level == 0:
            # δ2 and flow of the points hidden at t2: once, at the end (Params.hidden_fill_sigma);
            # δ2 also where the searches or the level's start found the point hidden, and
            # where its flow finds no match at t2: its t2 samples, read at p + (u, v), show
            # another point: the δ2 they gave is that point's. Where the flow is lost
            # (further off than the warps pull back, or the point is hidden at t2 and its
            # flow found another point), the fill gives it its surface's motion too
            flagged, lost = hidden_here, None
            if not solver.flow_only and params.hidden_fill_sigma > 0:
                flagged, lost = _unmatched(cen[0], cen[1], solver.x, params, dev, floor())
                if hidden_here is not None:
                    _device.launch_rows(fusion.either_above, dim=(h, w), inputs=[hidden_here, 0.5, flagged, 0.5],
                                        outputs=[flagged], device=dev)
            solver.fill_hidden(flagged, lost)
            lap("iterate")
            # the flow's median once more, after the fill set the hidden points' flow (the
            # last warp's median came before it). It runs whether or not the fill changed
            # anything: flow only, or with hidden_fill_sigma = 0, it is a second pass of the
            # median (160×120: EPE 0.978× over 63 scenes, none worse; flow only, `paper` at
            # 320×240, 0.162 → 0.151)
            solver.median()
            lap("median")
            if fit_surfaces:
                _fit_solver_surfaces(solver, cen, hidden_here, params, dev, floor())
                lap("median")
            if params.outline_relabel and not solver.flow_only:
                _relabel_outlines(solver, cen, params, dev, floor())
                lap("search")
        if level > 0:
            fh, fw = sizes[level - 1]
            sx, sy = fw / w, fh / h
            sd = 0.5 * (sx + sy)
            if solver.flow_only:
                x, = _upsample_state([solver.unknowns()], (fh, fw), (sd, sd, sx, sy), dev)
            else:
                x_dev = wp.empty((fh, fw), dtype=wp.vec4, device=dev)
                _device.launch_rows(pyramid.upsample_unknowns, dim=(fh, fw),
                                    inputs=[solver.x, wp.vec4(sd, sd, sx, sy), 4], outputs=[x_dev], device=dev)
            coarser = solver
        else:
            x = solver.unknowns()
        lap("upsample")
    if params.depth_change_radius > 0 and n_samples > 1:
        x = _depth_change_median(x, params, dev)
        lap("median")
    if colour is not None and params.colour_median_radius > 0:
        x = _colour_edges(x, colour, params, dev)
        lap("median")
    if n_samples > 1 and params.speckle_radius > 0:
        x = _remove_speckles(x, params, dev)
        lap("median")

    if unmatched > FLOW_UNMATCHED_SHARE and not _IN_PILOT.get():   # (the exposure pilot's run: not the user's)
        left = _match_residual(cen.numpy(), x[..., 2], x[..., 3])
        if left > FLOW_UNMATCHED_RESIDUAL:
            _warn(f"{source}: the flow search found no clear match in t2 for {unmatched:.0%} of the pixels, and the "
                  f"flow estimated leaves t2 unlike t1 (a median difference of {left:.3g} times that of neighbouring "
                  f"pixels): the motion may reach beyond the ±{flow_range:g} px searched (flow_range), or the two "
                  "light fields do not show the same scene; the flow and δ2 are not to be trusted", say)
    occluded = None if solver.flow_only else solver.occluded_at(x)
    lap("occlusion")
    return SceneFlow(
        disp1=x[..., 0].copy(), disp2=x[..., 1].copy(), u=x[..., 2].copy(), v=x[..., 3].copy(),
        params=requested, radius=float(radius), device=dev, timings=timings,
        exposure=(None if exposure_fit is None or exposure_fit.change == 0.0
                  else (exposure_fit.gain, exposure_fit.shift)),
        occluded=occluded, made_with=made_with(),
    )


def made_with() -> dict[str, str]:
    """The versions an estimate is made with, as a result records them (``made_with`` in
    ``sceneflow.npz``): lfsf's, Python's, NumPy's and Warp's (the same settings gave other
    maps where Warp's code generation changed; lfsf's own version says which settings it
    knew)."""
    import platform

    from lfsf import __version__

    return {"lfsf": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "warp": str(_device.warp().__version__)}


def _centre_colour(lf: LightField, offset: float, stretch: float) -> np.ndarray | None:
    """The RGB centre view of a colour light field (:attr:`LightField.centre`), float32
    (H, W, 3), stretched as the luma is; None for grey light fields, and for grey ones
    stored as RGB: where 99 % of the pixels have channels within GREY_CHROMA of each
    other (after the stretch, so that the test reads the same at any intensity scale),
    the colour steps would see the luma alone, which they do not improve (grey copies
    of `weak_texture` at 64×48, `fast`: δ1 MSE 0.0044 → 0.0098 with the edge step)."""
    if not lf.is_colour:
        return None
    out = np.array(lf.centre, np.float32)  # (a copy: a slice would hold the whole light field)
    if stretch != 1.0:
        out = (out - np.float32(offset)) * np.float32(stretch)
    chroma = np.ptp(out, axis=-1)
    if float(np.percentile(chroma, 99)) <= GREY_CHROMA:
        return None
    return out


def _depth_change_median(x: np.ndarray, params: Params, device: str) -> np.ndarray:
    """δ2 = δ1 + the median of δ2 − δ1 over its own surface (``Params.depth_change_radius``),
    at full resolution: the flow's median over one surface
    (:func:`lfsf.kernels.median.median_flow`, the same window, tolerance and ties) run on
    the depth change put in the flow's place."""
    from lfsf.solver import flow_median, level_median_radius

    wp = _device.warp()
    x = np.asarray(x, np.float32)
    guide = x.copy()
    guide[..., 2] = guide[..., 3] = x[..., 1] - x[..., 0]
    out = wp.empty(x.shape[:2], dtype=wp.vec4, device=device)
    flow_median(wp.array(guide, dtype=wp.vec4, device=device),
                level_median_radius(params.depth_change_radius, x.shape[1]), params.median_tolerance, out, device)
    out = out.numpy()
    result = x.copy()
    result[..., 1] = x[..., 0] + out[..., 2]
    return result


def _map_step(kernel, x: np.ndarray, inputs, device: str) -> np.ndarray:
    """One of the end steps: ``kernel`` (x, then ``inputs``; out, both vec4 (H, W) maps)
    launched over x (H, W, 4) on ``device``, its result back on the host."""
    wp = _device.warp()
    h, w = x.shape[:2]
    out = wp.empty((h, w), dtype=wp.vec4, device=device)
    _device.launch_rows(kernel, dim=(h, w),
                        inputs=[wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec4, device=device), *inputs],
                        outputs=[out], device=device)
    return out.numpy()


def _remove_speckles(x: np.ndarray, params: Params, device: str) -> np.ndarray:
    """δ1 and δ2 of x (H, W, 4) cleared of speckles (``params.speckle_radius``,
    SPECKLE_DEPTH, SPECKLE_SUPPORT; :func:`lfsf.kernels.median.remove_speckles`)."""
    from lfsf.kernels import median

    return _map_step(median.remove_speckles, x, [params.speckle_radius, SPECKLE_DEPTH, SPECKLE_SUPPORT], device)


def _colour_edges(x: np.ndarray, colour: np.ndarray, params: Params, device: str) -> np.ndarray:
    """δ1 and δ2 of x (H, W, 4) snapped to the colour edges of the t1 centre view
    (``Params.colour_median_radius``, :func:`lfsf.kernels.median.guided_median_edges`)."""
    from lfsf.kernels import median

    wp = _device.warp()
    colours = wp.array(np.ascontiguousarray(colour), dtype=wp.vec3, device=device)
    return _map_step(median.guided_median_edges, x, [colours, params.colour_median_radius, COLOUR_SIGMA, COLOUR_JUMP,
                                                     params.colour_median_separation], device)


def _intensity_stretch(lf1: LightField, lf2: LightField, ranges=None) -> tuple[float, float]:
    """(offset, factor) taking the two light fields' joint intensity range (``ranges``:
    each one's (lowest, highest) value, where already found) to [0, 1]
    where it spans less than MIN_INTENSITY_RANGE or more than MAX_INTENSITY_RANGE (counts
    given as floats, e.g. [0, 255]: δ1 BadPix 5.5 % against 4.2 %, EPE 0.096 against
    0.077 on the scene below); (0, 1) otherwise (the views as they are). The diffusion
    tensor Γ = exp(−γ|∇I|^β) and the ROF weight μ take intensities in [0, 1]: 12-bit
    data stored in 16 bits (read as [0, 1/16]), or an underexposed capture, would
    otherwise see almost no edges and an over-smoothed texture part.
    ``paper`` at 128×96 with 7×7 views, BadPix(0.07) of δ1: 4.2 % as rendered; at 1/16
    of its range, as 12-bit data in 16 bits, 15.8 % unstretched and 3.9 % stretched; in
    [0.49, 0.51], 19.3 % and 4.0 %. Matching depends on differences only, so the
    offset changes nothing else."""
    if ranges is None:
        ranges = [(float(np.min(lf.views)), float(np.max(lf.views))) for lf in (lf1, lf2)]
    lo, hi = min(r[0] for r in ranges), max(r[1] for r in ranges)
    span = hi - lo
    if span <= 0.0 or MIN_INTENSITY_RANGE <= span <= MAX_INTENSITY_RANGE:
        return 0.0, 1.0
    return lo, 1.0 / span


def _box_down(image: np.ndarray, factor: int) -> np.ndarray:
    """Means over factor × factor blocks (the last partial rows and columns dropped)."""
    if factor <= 1:
        return np.asarray(image, np.float64)
    h, w = image.shape[0] // factor, image.shape[1] // factor
    return np.asarray(image[:h * factor, :w * factor], np.float64).reshape(h, factor, w, factor).mean((1, 3))


def _l1_line(x: np.ndarray, y: np.ndarray, weight: np.ndarray, span: float) -> tuple[float, float] | None:
    """(g, b) minimising Σ weight·|y − g·x − b| (iteratively reweighted least squares)."""
    gain, shift = 1.0, 0.0
    for _ in range(30):
        wt = weight / np.maximum(np.abs(y - gain * x - shift), 1e-4 * span)
        sw, sx, sy = wt.sum(), (wt * x).sum(), (wt * y).sum()
        det = sw * (wt * x * x).sum() - sx * sx
        if not det > 0.0:
            return None
        gain = (sw * (wt * x * y).sum() - sx * sy) / det
        shift = (sy - gain * sx) / sw
    return float(gain), float(shift)


def _flow_scale(u: np.ndarray, v: np.ndarray, where: np.ndarray) -> float:
    """How much the scene grew along each axis from t1 to t2 by the flow (u, v): the
    median over ``where`` of √|det(1 + ∇(u, v))| (1 for a translation, 1.05 for a zoom of
    5 %), within 1/2 … 2; 1 where it is within EXPOSURE_SCALE_TOLERANCE of 1 (the flow's
    noise, and a change of blur too small to tell) or nothing is left to take it from."""
    du_y, du_x = np.gradient(u.astype(np.float64))
    dv_y, dv_x = np.gradient(v.astype(np.float64))
    det = np.abs((1.0 + du_x) * (1.0 + dv_y) - du_y * dv_x)[where]
    if det.size == 0:
        return 1.0
    scale = float(np.sqrt(np.median(det)))
    if not np.isfinite(scale) or abs(scale - 1.0) < EXPOSURE_SCALE_TOLERANCE:
        return 1.0
    return min(max(scale, 0.5), 2.0)


def _weighted_median(values: np.ndarray, weight: np.ndarray) -> float:
    """The value m minimising Σ weight·|values − m|."""
    order = np.argsort(values)
    cum = np.cumsum(weight[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


class Exposure(NamedTuple):
    """A change of exposure from t1 to t2 (:func:`_exposure_change`): the line I1 ≈ g·I2 + b,
    how far it moves t2's intensities (a fraction of the range), and, where the line
    leaves bands of intensities bowed off it (:func:`_tone_curve`), a tone curve (knots
    x, y: t2's intensities and the t1 ones they match, increasing) that can replace it;
    None otherwise; and the largest band's median residual off the line (a fraction of
    the range)."""
    gain: float
    shift: float
    change: float
    curve: tuple[np.ndarray, np.ndarray] | None = None
    departure: float = 0.0
    #: the pilot's flow (u, v) on the centre views box-averaged by ``factor``: (u, v, factor)
    pilot: tuple[np.ndarray, np.ndarray, int] | None = None
    #: a smooth field added to t2 after the line or curve (:func:`_local_light`): (field in
    #: t2's coordinates at the pilot's size, its factor)
    light: tuple[np.ndarray, int] | None = None

    def apply(self, values: np.ndarray) -> np.ndarray:
        """t2's intensities (images, the last two axes rows and columns) mapped onto t1's:
        by the curve (its ends continued with the line's slope), else by the line; then
        plus the local field, where there is one."""
        if self.curve is None:
            out = values * np.float32(self.gain)
            out += np.float32(self.shift)
        else:
            x, y = self.curve
            out = np.interp(values, x, y).astype(np.float32)
            low, high = values < x[0], values > x[-1]
            out[low] = y[0] + self.gain * (values[low] - x[0])
            out[high] = y[-1] + self.gain * (values[high] - x[-1])
        if self.light is not None:
            field, factor = self.light
            height, width = out.shape[-2:]
            # the pilot's pixel k covers the pixels k·factor … (k + 1)·factor − 1
            yy, xx = np.mgrid[0:height, 0:width].astype(np.float64)
            at = (factor - 1) / 2.0
            out += _bilinear(field, (xx - at) / factor, (yy - at) / factor).astype(np.float32)
        return out


def _tone_curve(x: np.ndarray, y: np.ndarray, weight: np.ndarray, gain: float, shift: float,
                span: float) -> tuple[tuple[np.ndarray, np.ndarray] | None, float]:
    """Knots of a tone curve y ≈ f(x) (:class:`Exposure`) where the line g·x + b leaves, in
    one of EXPOSURE_CURVE_BINS bands of x of equal counts, a weighted median residual
    above EXPOSURE_CURVE_MIN of ``span`` and the bands' residuals bow across the range by
    more than EXPOSURE_CURVE_BOW; None where the line fits every band, or one band
    strays alone. Each knot is a band's weighted medians of x and of the residual (on
    the line), made non-decreasing. Returns (the knots or None, the largest band's
    residual / ``span``)."""
    edges = np.quantile(x, np.linspace(0.0, 1.0, EXPOSURE_CURVE_BINS + 1))
    residual = y - (gain * x + shift)
    knots_x, off = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        band = (x >= lo) & (x <= hi)
        if band.sum() < 16:
            continue
        knots_x.append(_weighted_median(x[band], weight[band]))
        off.append(_weighted_median(residual[band], weight[band]))
    departure = max((abs(v) for v in off), default=0.0) / span
    if len(off) < 3 or departure <= EXPOSURE_CURVE_MIN:
        return None, departure
    kx = np.asarray(knots_x, np.float64)
    # the bands' departures as a bow a·(t² − t) + c over t = the knots' places in [0, 1]: a
    # tone curve bends the whole range, a pilot's flow gone wrong in one band of
    # intensities (an object's) makes one band stray
    t = (kx - kx[0]) / max(float(kx[-1] - kx[0]), 1e-12)
    bow = abs(float(np.linalg.lstsq(np.c_[t * t - t, np.ones_like(t)], np.asarray(off), rcond=None)[0][0])) / 4.0
    if bow <= EXPOSURE_CURVE_BOW * span:
        return None, departure
    ky = np.maximum.accumulate(gain * kx + shift + np.asarray(off))
    keep = np.concatenate([[True], np.diff(kx) > 0])  # (np.interp wants x increasing)
    return (kx[keep], ky[keep]), departure


def _joint_span(centre1: np.ndarray, centre2: np.ndarray) -> float:
    """The two views' joint range, from the 0.1th to the 99.9th percentile (robust to a few
    hot or dead pixels): what the exposure fit's and the local field's levels are
    fractions of."""
    ends1, ends2 = np.percentile(centre1, [0.1, 99.9]), np.percentile(centre2, [0.1, 99.9])  # (a sort each)
    return float(max(ends1[1], ends2[1]) - min(ends1[0], ends2[0]))


def _pilot_matches(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, keep): where the exposure pilot's flow (u, v) takes each pixel, and the
    pixels kept: those 2 px or more inside the border whose match lies in the image."""
    h, w = u.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    x_at, y_at = xx + u, yy + v
    keep = (x_at >= 0) & (x_at <= w - 1) & (y_at >= 0) & (y_at <= h - 1)
    keep[:2] = keep[-2:] = False
    keep[:, :2] = keep[:, -2:] = False
    return x_at, y_at, keep


def _flat_weights(image: np.ndarray, keep: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    """(|∇I|, 1 / (1 + (|∇I| / s)²)) of ``image``, s the 75th percentile of |∇I| over the
    ``keep`` pixels (at least 0.1 % of ``span``): flat pixels weigh most, where a flow
    error changes the compared value least; where most of the image is flat (a sky, a
    wall) its textured part still counts."""
    gy, gx = np.gradient(image)
    grad = np.hypot(gx, gy)
    scale = max(float(np.percentile(grad[keep], 75.0)), 1e-3 * span)  # (an exactly flat image has 0)
    return grad, 1.0 / (1.0 + (grad / scale) ** 2)


def _exposure_change(centre1: np.ndarray, centre2: np.ndarray, device: str, note=None) -> Exposure:
    """(g, b, change, curve, departure): a global change of exposure from t1 to t2,
    I1(p) ≈ g·I2(p + u) + b or a tone curve f(I2(p + u)) (:class:`Exposure`;
    ``Params.match_exposure``), from the grey centre views.

    A flow-only pilot (the ``flow`` preset with θ = EXPOSURE_THETA) on the views
    box-averaged by the largest whole factor that leaves at least EXPOSURE_SIZE px along
    their longer side and EXPOSURE_MIN_SHORT along the shorter, t2 scaled by the ratio of
    the two views' mean gradients (within EXPOSURE_MAX_GAIN either way), gives the
    correspondences p ↔ p + u.
    Over them, on the two views blurred by EXPOSURE_BLUR (t2's by as much more as the
    scene grew, :func:`_flow_scale`), L1 fits (iteratively
    reweighted least squares) of I1 on I2(p + u) and of I2(p + u) on I1 give g as the
    geometric mean of their slopes, and b is the weighted median of I1 − g·I2(p + u).
    Each pixel is weighted by 1 / (1 + (|∇I1| / s)²), s the 75th percentile of |∇I1| (at
    least 0.1 % of the range): on flat pixels a flow error changes the compared value
    least. The fit is refused where the two slopes disagree (EXPOSURE_AGREEMENT) or the
    gain is implausible (EXPOSURE_MAX_GAIN). Pixels within 2 px of the border, whose match
    leaves the image, or that the blur mixes with values within 2 % of the ends of the
    range at either time (clipped) take no part. ``change`` is the largest of
    |g·x + b − x| over the 5th and 95th percentiles x of I2, as a fraction of the two
    views' joint range (from the 0.1th to the 99.9th percentile); (1, 0, 0) when there is
    too little to fit. Only where that exceeds EXPOSURE_CHANGE is a tone curve looked for
    (:func:`_tone_curve`, over the same pixels and weights): on pairs of one exposure the
    bands' medians stray by up to 2 % of the range (a looming object's blur, a pilot's
    flow off in one band of intensities; 9 of 80 pairs above EXPOSURE_CURVE_MIN), where
    no change is matched at all. ``note`` (a callable taking a line) hears why a fit
    that found a gain was refused."""
    lo = min(float(centre1.min()), float(centre2.min()))
    hi = max(float(centre1.max()), float(centre2.max()))
    span = _joint_span(centre1, centre2)  # (what `change` is a fraction of)
    if not np.isfinite(span) or span <= 0.0 or not hi > lo:
        return Exposure(1.0, 0.0, 0.0)
    # (down: the pilot never below 160 px along the longer side, nor below 48 along the shorter)
    factor = max(1, min(max(centre1.shape[:2]) // EXPOSURE_SIZE, min(centre1.shape[:2]) // EXPOSURE_MIN_SHORT))
    a, b = _box_down(centre1, factor), _box_down(centre2, factor)
    h, w = a.shape
    if min(h, w) < 8:
        return Exposure(1.0, 0.0, 0.0)
    # (3 warps, as the pilot was measured with: the `flow` preset's own went to 5 in the
    # forty-fourth session, which took the pilot from 0.33 to 0.39 s at 640×480 for the
    # same fit to 3e-4)
    pilot = Params.preset("flow").replace(warps=EXPOSURE_WARPS, texture_theta=EXPOSURE_THETA,
                                          search_radius=EXPOSURE_SEARCH_RADIUS, match_exposure=False)
    # the pilot sees t2 scaled to t1's mean gradient: the estimator scales both times by
    # t1's contrast (_normalise_contrast), so that unscaled a darker t1 would make t2's
    # texture outweigh the regulariser, and the pilot's flow failed where the same change
    # the other way round was matched (t1 at 0.35× t2: EPE 10.6 against 0.13)
    pre = _mean_gradient(a) / max(_mean_gradient(b), 1e-12)
    pre = min(max(pre, 1.0 / EXPOSURE_MAX_GAIN), EXPOSURE_MAX_GAIN) if np.isfinite(pre) and pre > 0 else 1.0
    flow = pilot_estimate(a[None, None].astype(np.float32), (pre * b)[None, None].astype(np.float32), pilot,
                          device)
    pilot_flow = (flow.u, flow.v, factor)  # (for the local field, _local_light)
    # clipped pixels (within 2 % of the ends of the values), and those the blur mixes them into
    edge = 0.02 * (hi - lo)
    x_at, y_at, keep = _pilot_matches(flow.u, flow.v)
    # t2 blurred by as much more as the scene grew from t1 to t2 (its scale: the median of
    # √|det(1 + ∇u)|), so that both blurs take in the same patch of the scene: alike, a
    # surface that came nearer kept more contrast at t2 than at t1, which read as a gain
    # (a zoom of 5 % as 0.96·I + 0.02, and the flow's error doubled)
    scale = _flow_scale(flow.u, flow.v, keep)
    blurs = (EXPOSURE_BLUR, EXPOSURE_BLUR * scale)
    clipped = [_blur(((img <= lo + edge) | (img >= hi - edge)).astype(np.float64), sigma)
               for img, sigma in zip((a, b), blurs)]
    a, b = _blur(a, blurs[0]), _blur(b, blurs[1])
    warped = _bilinear(b, x_at, y_at)
    keep &= (clipped[0] < 0.01) & (_bilinear(clipped[1], x_at, y_at) < 0.01)
    if keep.sum() < 64:
        return Exposure(1.0, 0.0, 0.0)
    weight = _flat_weights(a, keep, span)[1][keep]
    x, y = warped[keep], a[keep]
    # both ways, y on x and x on y, and g their geometric mean: noise, and the pilot's
    # errors, in the values regressed on bias a one-way fit's slope towards 0 (with sensor
    # noise of σ = 0.01 it read up to 0.58 % changes on brightness-constant scenes; 0.19 %)
    fits = [_l1_line(x, y, weight, span), _l1_line(y, x, weight, span)]
    if any(fit is None or not fit[0] > 0.0 for fit in fits):
        return Exposure(1.0, 0.0, 0.0, pilot=pilot_flow)
    gain = math.sqrt(fits[0][0] / fits[1][0])
    if fits[0][0] * fits[1][0] < EXPOSURE_AGREEMENT:
        if note is not None:
            note(f"exposure: not matched, the fit's two slopes disagree (gain {gain:.3f}, agreement "
                 f"{fits[0][0] * fits[1][0]:.3f} < {EXPOSURE_AGREEMENT})")
        return Exposure(1.0, 0.0, 0.0, pilot=pilot_flow)
    if not 1.0 / EXPOSURE_MAX_GAIN <= gain <= EXPOSURE_MAX_GAIN:
        if note is not None:
            note(f"exposure: not matched, the gain fitted ({gain:.3f}) is beyond the "
                 f"{EXPOSURE_MAX_GAIN:g}× (either way) that is undone")
        return Exposure(1.0, 0.0, 0.0, pilot=pilot_flow)
    shift = _weighted_median(y - gain * x, weight)
    ends = np.percentile(centre2, [5.0, 95.0])
    change = max(abs(gain * float(q) + shift - float(q)) for q in ends) / span
    if change <= EXPOSURE_CHANGE:  # (no change of exposure to undo: no curve either)
        return Exposure(float(gain), float(shift), float(change), pilot=pilot_flow)
    return Exposure(float(gain), float(shift), float(change), *_tone_curve(x, y, weight, gain, shift, span),
                    pilot=pilot_flow)


def _local_light(centre1: np.ndarray, centre2: np.ndarray, pilot) -> tuple[np.ndarray, int, float, float] | None:
    """A change of brightness over part of the view between t1 and t2 (a glare, a shadow
    that comes or goes): a smooth field F in t2's coordinates with I1(p) ≈ I2(p + u) +
    F(p + u), or None where none explains enough of the view (:data:`LOCAL_LIGHT_AREA`).
    ``centre2`` is the t2 centre view already matched to t1 globally (the line or the
    tone curve, where one is applied); ``pilot`` the exposure pilot's flow (u, v, factor)
    on the centre views box-averaged by ``factor`` (:attr:`Exposure.pilot`).

    On the averaged views (blurred by 1 px), each pixel p's residual r(p) = I1(p) −
    I2(p + u), weighted as the exposure fit weighs it (flat pixels most), is splatted to
    its nearest pixel of t2 and both sums smoothed by a Gaussian of LOCAL_LIGHT_SIGMA px
    (a normalised convolution); the field fades to 0 where few residuals land (a quarter
    of the median density: parts hidden at t1 or carried out of view). Then, in
    LOCAL_LIGHT_ROUNDS rounds, residuals far from the field count less (weights 1 / (1 +
    ((r − F) / s)²), s LOCAL_LIGHT_ROBUST of the range): a pilot's flow error near a
    moving object leaves a residual of the texture's size and either sign, no smooth
    field. None too where what the field explains lies in thin bands only
    (:data:`LOCAL_LIGHT_CORE`: an outline's, where a surface came to cover another) or
    where the pilot's flow does not hold (:data:`LOCAL_LIGHT_MATCH`). Returns (F, factor,
    the share of the view it explains, its largest value as a fraction of the range)."""
    u, v, factor = pilot
    span = _joint_span(centre1, centre2)
    a, b = _blur(_box_down(centre1, factor), 1.0), _blur(_box_down(centre2, factor), 1.0)
    h, w = a.shape
    if not np.isfinite(span) or span <= 0.0 or u.shape != (h, w) or min(h, w) < 16:
        return None
    x_at, y_at, keep = _pilot_matches(u, v)
    if keep.sum() < 64:
        return None
    r = a - _bilinear(b, x_at, y_at)
    grad, flat = _flat_weights(a, keep, span)
    base = np.where(keep, flat, 0.0)
    qx = np.clip(np.rint(x_at).astype(np.int64), 0, w - 1)[keep]
    qy = np.clip(np.rint(y_at).astype(np.int64), 0, h - 1)[keep]
    r_kept = r[keep]
    weight = base[keep]
    field = np.zeros((h, w))
    for _ in range(LOCAL_LIGHT_ROUNDS):
        num, den = np.zeros((h, w)), np.zeros((h, w))
        np.add.at(num, (qy, qx), weight * r_kept)
        np.add.at(den, (qy, qx), weight)
        num, den = _blur(num, LOCAL_LIGHT_SIGMA), _blur(den, LOCAL_LIGHT_SIGMA)
        landed = den[den > 0]
        if landed.size == 0:
            return None
        cover = np.clip(den / (0.25 * float(np.median(landed))), 0.0, 1.0)
        field = np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0) * cover
        off = r_kept - field[qy, qx]
        weight = base[keep] / (1.0 + (off / (LOCAL_LIGHT_ROBUST * span)) ** 2)
    at_q = field[qy, qx]
    explained = (np.abs(at_q) > LOCAL_LIGHT_LEVEL * span) & (np.abs(r_kept - at_q) < 0.5 * np.abs(at_q))
    # (the share of the view less a 4-px border, as measured)
    inner = np.zeros((h, w), bool)
    inner[4:-4, 4:-4] = True
    share = float(np.count_nonzero(explained & inner[keep])) / max(int(inner.sum()), 1)
    if share <= LOCAL_LIGHT_AREA:
        return None
    # … and not only in thin bands (a surface that came to cover another, carried there by
    # the pilot's smooth flow, leaves a band of one sign along its outline): the pixels
    # whose whole (2 LOCAL_LIGHT_CORE + 1)² box is explained
    explained_map = np.zeros((h, w), np.float32)
    explained_map[keep] = explained
    core = box_mean(explained_map, 2 * LOCAL_LIGHT_CORE + 1) > 0.999
    if not float(np.mean(core[inner])) > LOCAL_LIGHT_CORE_AREA:
        return None
    # the pilot's flow must hold where the texture is (else the residual is two images'
    # difference, smooth where they are): there the residual less the field, as a distance
    # along the gradient (px), must be under LOCAL_LIGHT_MATCH
    grad_kept = grad[keep]
    textured = grad_kept >= np.percentile(grad_kept, 75.0)
    miss = float(np.median(np.abs(r_kept - at_q)[textured])) / max(float(np.median(grad_kept[textured])), 1e-12)
    if not miss < LOCAL_LIGHT_MATCH:
        return None
    return field.astype(np.float32), int(factor), share, float(np.max(np.abs(field))) / span


#: The largest magnitude a starting disparity or flow may have (px): far beyond any image,
#: and far from float32's end (u = 1e38 overflowed in the pyramid's upsampling, an
#: IndexError).
MAX_START_VALUE = 1e6


def _view_steps(radius: float) -> str:
    """"view step" or "view steps", as ``radius`` reads (R = 1 view step)."""
    return "view step" if radius == 1 else "view steps"


def _check_init(init, height: int, width: int) -> np.ndarray | None:
    """A starting estimate as one (H, W, 4) array [δ1, δ2, u, v], checked."""
    if init is None:
        return None
    return _checked_maps(init, "init", (height, width))


def _checked_maps(maps, what: str, shape: tuple[int, int] | None = None) -> np.ndarray:
    """δ1, δ2, u, v of a SceneFlow or a dict as one (H, W, 4) float32 array, or a
    ValueError starting with ``what``: a missing key, maps of another ``shape`` (or, with
    none given, not 2-D and alike), NaN or infinite values."""
    maps = maps.as_dict() if isinstance(maps, SceneFlow) else maps
    if not isinstance(maps, Mapping):
        raise ValueError(f"{what} must be a SceneFlow or a dict with disp1, disp2, u and v, "
                         f"got {type(maps).__name__}")
    try:
        arrays = [np.asarray(maps[k], np.float32) for k in ("disp1", "disp2", "u", "v")]
    except (KeyError, TypeError, ValueError):
        raise ValueError(f"{what} must be a SceneFlow or a dict with disp1, disp2, u and v "
                         f"(2-D maps), got keys {', '.join(map(str, maps)) or 'none'}") from None
    shape = arrays[0].shape if shape is None else tuple(shape)
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"{what}: disp1 should be a 2-D map, got shape {shape}")
    for name, a in zip(("disp1", "disp2", "u", "v"), arrays):
        if a.shape != shape:
            raise ValueError(f"{what}: {name} is {a.shape}, expected {shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"{what}: {name} has NaN or infinite values")
        if a.size and float(np.abs(a).max()) > MAX_START_VALUE:
            raise ValueError(f"{what}: {name} reaches {float(np.abs(a).max()):g} px, beyond the "
                             f"{MAX_START_VALUE:g} px a disparity or flow may start from")
    return np.stack(arrays, -1)


def predict_next(previous: SceneFlow | Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The estimate of the next pair of a sequence predicted from this pair's, assuming
    every point keeps its motion (image velocity and change of disparity).

    ``previous`` holds δ1, δ2, u, v of frame k's centre view (pair k → k + 1). A point seen
    at q in frame k is at q + u(q) in frame k + 1 with disparity δ2(q); there the next
    pair starts with δ1 = δ2(q), flow u(q) and δ2 = δ2(q) + (δ2 − δ1)(q). Points are
    splatted to their nearest pixel, the nearer (larger δ) winning where several land;
    pixels nothing lands on take the value found at p − u(p).

    Raises ``ValueError`` for a missing map, maps of different shapes, or NaN or
    infinite values.
    """
    maps = _checked_maps(previous, "predict_next: previous")
    d1, d2, u, v = (maps[..., c] for c in range(4))
    h, w = d1.shape
    moved = np.stack([d2, 2 * d2 - d1, u, v], -1)  # what each point carries to frame k + 1
    yy, xx = np.mgrid[0:h, 0:w]
    tx = np.rint(xx + u).astype(np.int64)
    ty = np.rint(yy + v).astype(np.int64)
    inside = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
    target = (ty * w + tx)[inside]
    carried = moved[inside]
    # nearest first wins: sort by target, then by δ descending, keep the first of each target
    order = np.lexsort((-carried[:, 0], target))
    target, carried = target[order], carried[order]
    first = np.ones(len(target), bool)
    first[1:] = target[1:] != target[:-1]
    out = np.full((h * w, 4), np.nan, np.float32)
    out[target[first]] = carried[first]
    out = out.reshape(h, w, 4)
    holes = np.isnan(out[..., 0])
    if holes.any():
        back = np.stack([_sample_at_flow(moved[..., c], np.stack([d1, d2, -u, -v], -1)) for c in range(4)], -1)
        out[holes] = back[holes]
    return {"disp1": out[..., 0], "disp2": out[..., 1], "u": out[..., 2], "v": out[..., 3]}


def _stack2(images, device):
    wp = _device.warp()
    h, w = images[0].shape
    out = wp.empty((2, h, w), dtype=float, device=device)
    for k, img in enumerate(images):
        wp.copy(out, img, dest_offset=k * h * w, count=h * w)
    return out

