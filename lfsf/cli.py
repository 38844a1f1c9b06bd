"""The ``lfsf`` command line (see INTERFACE.md).

Bad input ends with one line ``lfsf <command>: error: <what and where>`` on stderr and exit
status 2, never a traceback; every file is written under a temporary name and renamed.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import errno
import os
import re
import sys
import time
import warnings
from pathlib import Path

from lfsf._errors import (EXIT_BAD_INPUT, EXIT_HUNG_UP, EXIT_INTERRUPTED, EXIT_TERMINATED, ArgumentParser, LfsfWarning,
                          run_script)
from lfsf._files import output_file, output_folder, refuse_replacing_inputs, resolved


def _log(args, message: str) -> None:
    if not getattr(args, "quiet", False):
        print(message, file=sys.stderr, flush=True)


def _whole(text: str) -> int:
    """A whole number, or argparse's error saying so (not "invalid _size value")."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def _size(text: str) -> int:
    value = _whole(text)
    if value < 8:
        raise argparse.ArgumentTypeError(f"image size must be at least 8 pixels, got {value}")
    return value


def _folder_name(text: str) -> Path:
    """An output folder: '' would silently be the current folder (Path('') is '.')."""
    if not text:
        raise argparse.ArgumentTypeError("an empty folder name (it would be the current folder; give '.' for that)")
    return Path(text)


def _file_name(text: str) -> Path:
    """An output file: 'new/' would silently be the file 'new' (Path drops the slash)."""
    if not text or text.endswith(("/", os.sep)):
        raise argparse.ArgumentTypeError(f"{text!r} names a folder, not a file to write")
    return Path(text)


#: ``--json -``: the JSON on stdout, what a command prints besides it on stderr.
JSON_TO_STDOUT = "-"


def _report_name(text: str) -> Path | str:
    """``--json``'s file (:func:`_file_name`), or '-' alone, kept as the text '-': the
    report on stdout (:data:`JSON_TO_STDOUT`); './-' is a file named '-'."""
    return text if text == JSON_TO_STDOUT else _file_name(text)


def _input_name(text: str) -> Path:
    """An input file: '' would read as the current folder ('.')."""
    if not text:
        raise argparse.ArgumentTypeError("an empty file name")
    return Path(text)


def _device_name(text: str) -> str:
    """A device: '' had been taken for the default without a word."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty device name (leave --device out for the default)")
    return text


def _repeats(text: str) -> int:
    value = _positive(text)
    if value > 1000:
        raise argparse.ArgumentTypeError(f"at most 1000 timed runs, got {value}")
    return value


def _positive(text: str) -> int:
    value = _whole(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _grid(text: str) -> tuple[int, int]:
    """``--grid N`` (N×N views) or ``--grid ROWSxCOLS`` (``1x9``: a rig of one row) as
    (rows, cols), within the renderer's bounds."""
    from lfsf.synth import MAX_GRID

    parts = re.split(r"[x×]", text.strip().lower())
    if len(parts) > 2:
        raise argparse.ArgumentTypeError(f"expected N or ROWSxCOLS (e.g. 9 or 1x9), got {text!r}")
    try:
        sizes = [_positive(part) for part in parts]
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"expected N or ROWSxCOLS (e.g. 9 or 1x9), got {text!r}: {exc}") from None
    rows, cols = sizes if len(sizes) == 2 else sizes * 2
    if max(rows, cols) > MAX_GRID:
        raise argparse.ArgumentTypeError(f"at most {MAX_GRID} views a side, got {text}")
    return rows, cols


# --- synth ---------------------------------------------------------------------------------

def cmd_synth(args) -> int:
    from lfsf import synth
    from lfsf.device import resolve_device

    if args.list or args.scene is None:
        if not args.list:
            raise ValueError("name a scene (lfsf synth SCENE --out DIR) or use --list")
        for name, text in synth.list_scenes().items():
            print(f"{name:<14} {text}")
        print(f"{synth.RANDOM_PREFIX + 'N':<14} a scene drawn at random from seed N = 0, 1, … (the same N, "
              "the same scene)")
        return 0
    if args.out is None:
        raise ValueError("--out DIR is required")
    if args.frames < 2:
        raise ValueError(f"--frames must be at least 2 (2: one pair), got {args.frames}")
    scene = synth.get_scene(args.scene)  # unknown scene: clear error before any work
    try:
        synth.check_render(args.size, args.grid, args.supersample, args.frames, args.colour, args.noise)
    except ValueError as exc:  # (the option named: "noise sigma" is the library's word)
        raise ValueError(f"--noise: {exc}" if str(exc).startswith("noise sigma") else str(exc)) from None
    images = None
    if args.images is not None:  # photographs on the objects, each one's image and scale drawn by --image-seed
        if args.image_seed is not None and args.image_seed < 0:
            raise ValueError(f"--image-seed must be ≥ 0, got {args.image_seed}")
        images = synth.load_images(args.images)
        scene = synth.with_images(scene, len(images), seed=args.image_seed or 0)
    elif args.image_seed is not None:
        raise ValueError("--image-seed draws the images of --images FOLDER; give --images too")
    what = f"'{args.scene}'" + (f" with the {len(images)} images of {args.images}" if images else "")
    output_folder(args.out, create=False)
    device = resolve_device(args.device)
    width, height = args.size
    if args.frames > 2:
        if args.preview:
            raise ValueError("--preview is for a pair; a sequence (--frames) writes none")
        _log(args, f"rendering {what} at {width}×{height}, {args.grid[0]}×{args.grid[1]} views, "
                   f"{args.frames} frames, on {device} …")
        t0 = time.perf_counter()
        paths = synth.write_sequence(scene, args.out, args.frames, size=(width, height), grid=args.grid,
                                     supersample=args.supersample, colour=args.colour, device=device,
                                     noise=args.noise, images=images)
        _log(args, f"wrote {len(paths['frames'])} frames to {Path(args.out) / 'frames'} and the ground truth of "
                   f"each pair to {Path(args.out) / 'gt'} in {time.perf_counter() - t0:.1f} s")
        return 0
    # an earlier render's picture, which this render replaces with the rest of its files
    stale = None if args.preview or not synth.earlier_preview(args.out) else Path(args.out) / synth.PREVIEW_NAME
    output_folder(args.out, create=False, names=list(synth.SCENE_FILES) + [synth.PREVIEW_NAME] * args.preview)
    _log(args, f"rendering {what} at {width}×{height}, {args.grid[0]}×{args.grid[1]} views, t1 and t2, on {device} …")
    t0 = time.perf_counter()
    paths = synth.write_scene(scene, args.out, size=(width, height), grid=args.grid,
                              supersample=args.supersample, colour=args.colour, device=device, noise=args.noise,
                              images=images, preview=args.preview)
    _log(args, f"wrote {', '.join(str(p) for p in paths.values())} in {time.perf_counter() - t0:.1f} s")
    if stale is not None:
        _log(args, f"removed {stale}, an earlier render's (give --preview for this one's)")
    return 0


# --- eval ----------------------------------------------------------------------------------

def _json_on_stdout(args) -> bool:
    """Whether ``--json -`` asks for the JSON on stdout (for a pipe: ``lfsf eval R GT --json - | jq``)."""
    # (the text '-' itself: Path('./-') reads as '-' too, and is a file)
    return isinstance(getattr(args, "json", None), str) and args.json == JSON_TO_STDOUT


def _with_json_report(make_report):
    """A command whose ``make_report(args)`` prints its tables and returns the JSON
    report: written to ``--json FILE`` atomically (the file checked before any work), or
    with ``--json -`` to stdout, what it prints then going to stderr."""
    import functools

    @functools.wraps(make_report)
    def command(args) -> int:
        from lfsf._files import json_bytes, write_json_atomic

        on_stdout = _json_on_stdout(args)
        if args.json and not on_stdout:
            output_file(args.json)
        with contextlib.redirect_stdout(sys.stderr) if on_stdout else contextlib.nullcontext():
            report = make_report(args)
        if on_stdout:
            sys.stdout.write(json_bytes(report).decode("utf-8"))
            sys.stdout.flush()
        elif args.json:
            write_json_atomic(args.json, report)
        return 0

    return command


def _not_an_input(report: Path, result: Path, gt: Path) -> None:
    """Refuse a report path that is the ground truth, the result or one of a result
    folder's files: the JSON would replace what it reports on."""
    from lfsf.batch import RESULT_FILES
    from lfsf.evaluate import GT_FILES

    target = resolved(report)
    inputs = [gt, result] + ([result / name for name in (*RESULT_FILES, "overview.png")] if result.is_dir() else [])
    if gt.is_dir():  # (the ground truth read from the folder)
        inputs += [gt / name for name in GT_FILES]
    for path in inputs:
        if resolved(path) == target:
            raise ValueError(f"{report}: the report would replace {path}, which it reports on; choose another "
                             "--json file")


@_with_json_report
def cmd_eval(args) -> dict:
    import numpy as np

    from lfsf.evaluate import (VARIABLES, downsample_border, downsample_truth, evaluate, format_table, load_estimate,
                               load_ground_truth, recorded_downsample)

    if args.json and not _json_on_stdout(args):
        _not_an_input(args.json, args.result, args.gt)
    estimate = load_estimate(args.result)
    gt, default_border = load_ground_truth(args.gt)
    # a result of lfsf run --downsample K against the truth of the light fields' size: the
    # truth shrunk alike, and its border (K had been given to run alone, and eval failed)
    k = recorded_downsample(args.result)
    shape = next((np.shape(estimate[v]) for v in VARIABLES if v in estimate), None)
    shrunk = k > 1 and shape is not None and all(
        np.shape(a)[:2] != shape and (np.shape(a)[0] // k, np.shape(a)[1] // k) == shape
        for name, a in gt.items() if name in VARIABLES)
    if shrunk:
        gt, default_border = downsample_truth(gt, k), downsample_border(default_border, k)
    border = default_border if args.border is None else args.border
    try:
        errors = evaluate(estimate, gt, border=border)
    except ValueError as exc:
        raise ValueError(f"{args.result} against {args.gt}: {exc}") from None
    print(f"{args.result} against {args.gt} (border {border} px"
          + (f"; estimated on views shrunk {k} times, the ground truth shrunk alike){_shrunk_units(k)}"
             if shrunk else ")"))
    print(format_table(errors))
    # a partial result (one map written, another lost) should not pass for a whole one
    lacking = [name for name, keys in (("disp1", ("disp1",)), ("disp2", ("disp2",)), ("flow", ("u", "v")))
               if all(k in gt for k in keys) and not all(k in estimate for k in keys)]
    if lacking:
        from lfsf.evaluate import flow_only

        if flow_only(args.result):
            print(_not_estimated_line(args.result, lacking))
        else:
            print(f"not evaluated, missing from {args.result}: {', '.join(lacking)} (the ground truth has them)")
    # and what the ground truth lacks: half a flow, or the mask of the pixels to score
    notes = []
    for name in ("disp1", "disp2", "u", "v"):  # (their errors print as inf, and null in the JSON)
        if name in estimate:
            bad = int(np.size(estimate[name]) - np.isfinite(estimate[name]).sum())
            if bad:
                notes.append(f"{args.result}: {name} holds {bad} NaN or infinite value{'s' if bad > 1 else ''}; "
                             "where scored, its errors read inf")
    if ("u" in gt) != ("v" in gt):
        has, lacks = ("u", "v") if "u" in gt else ("v", "u")
        notes.append(f"flow not evaluated: {args.gt} has '{has}' but no '{lacks}'")
    if Path(args.gt).suffix.lower() == ".npz" and "valid" not in gt:
        finite = all(np.isfinite(gt[k]).all() for k in VARIABLES if k in gt)
        notes.append(f"every {'' if finite else 'finite '}pixel scored (but the border): {args.gt} holds no "
                     "'valid' mask" + ("" if finite else "; its NaN or infinite values are left out"))
    for note in notes:
        print(note)
    return {"result": str(args.result), "ground_truth": str(args.gt), "border": border, "errors": errors,
            "not_evaluated": lacking, "notes": notes}


def _shrunk_units(k: int) -> str:
    """What the errors of a result of ``--downsample K`` are in, for a table's header."""
    return (f": δ and the flow in the shrunk views' pixels, so against a full-size run's MSE ×{k * k}, EPE "
            f"×{k}, and BadPix(0.07) counts errors over {0.07 * k:g} of the full views' px")


def _camera(values: list[str]):
    """``--camera F B [D0]`` or ``--camera FILE`` as an lfsf.Camera."""
    from lfsf.camera import Camera

    if len(values) == 1:
        try:
            float(values[0])
        except ValueError:
            return Camera.from_file(values[0])
        raise ValueError(f"--camera {values[0]}: give the focal length f (px) and the baseline b (and δ0), or one "
                         "file (a gt.npz of 'lfsf synth', an HCI parameters.cfg or its folder)")
    if len(values) in (2, 3):
        try:
            numbers = [float(v) for v in values]
        except ValueError:
            raise ValueError(f"--camera {' '.join(values)}: give the focal length f (px), the baseline b and "
                             "optionally δ0 as numbers, or one file (a gt.npz of 'lfsf synth', an HCI "
                             "parameters.cfg)") from None
        try:
            return Camera(*numbers)
        except ValueError as exc:
            raise ValueError(f"--camera {' '.join(values)}: {str(exc).removeprefix('Camera: ')}") from None
    raise ValueError(f"--camera {' '.join(values)}: give F B [D0] (three numbers at most) or one file")


def cmd_points(args) -> int:
    from dataclasses import replace

    import numpy as np

    from lfsf.estimate import SceneFlow
    from lfsf.evaluate import downsample_of

    suffix = args.out.suffix.lower()
    if suffix not in (".ply", ".npz"):
        raise ValueError(f"{args.out}: write the points to a .ply (a point cloud) or an .npz (the maps), not "
                         f"{suffix or 'a file without a suffix'}")
    output_file(args.out)
    if args.colour is not None and suffix == ".npz":
        raise ValueError(f"--colour colours the points of a .ply; {args.out} (an .npz of maps) holds no colours")
    inputs = [args.result] + ([args.result / "sceneflow.npz"] if args.result.is_dir() else [])
    inputs += [Path(v) for v in args.camera[:1] if len(args.camera) == 1] + [args.colour, args.gt]
    if any(p is not None and p.exists() and resolved(p) == resolved(args.out) for p in inputs):
        raise ValueError(f"{args.out}: it would replace an input of this command; choose another --out")
    camera = _camera(args.camera)
    if args.principal is not None:
        try:
            camera = replace(camera, principal=tuple(args.principal))
        except ValueError as exc:
            raise ValueError(f"--principal {args.principal[0]:g} {args.principal[1]:g}: "
                             f"{str(exc).removeprefix('Camera: principal ')}") from None
    sf = SceneFlow.load(args.result)
    k = downsample_of(sf.inputs)  # (what SceneFlow.load read: not the file again)
    gt = None
    if args.gt is not None:  # (read and checked before the points are written)
        from lfsf.evaluate import load_ground_truth

        gt, _ = load_ground_truth(args.gt)
        lacking = [name for name in ("disp1", "disp2", "u", "v") if name not in gt]
        if lacking:
            raise ValueError(f"{args.gt}: no 3-D truth without {', '.join(lacking)} (a gt.npz of 'lfsf synth' "
                             "holds all four)")
        if k > 1 and np.shape(gt["disp1"]) != sf.disp1.shape:
            from lfsf.evaluate import downsample_truth

            gt = downsample_truth(gt, k)
        if np.shape(gt["disp1"]) != sf.disp1.shape:
            raise ValueError(f"{args.gt}: its maps are {np.shape(gt['disp1'])[1]}×{np.shape(gt['disp1'])[0]}, the "
                             f"result {args.result} {sf.disp1.shape[1]}×{sf.disp1.shape[0]}")
    given = camera  # (the light fields' camera, which sf.points and scene_flow_errors shrink as the result was)
    try:  # (of a result of lfsf run --downsample K: the camera shrunk K times, SceneFlow.maps_camera)
        points1, points2 = sf.points(camera)
        camera = sf.maps_camera(camera)  # (the maps' own, as the messages and the .npz give it)
        errors = None
        if gt is not None:  # (before anything is written)
            from lfsf.camera import scene_flow_errors
            from lfsf.evaluate import SYNTH_BORDER, downsample_border

            border = downsample_border(SYNTH_BORDER, k) if k > 1 else SYNTH_BORDER
            errors = scene_flow_errors(sf, gt, given, border=border)
    except ValueError as exc:
        said = str(exc).removeprefix("SceneFlow.points: ").removeprefix("Camera.points: ")
        said = said.split(" (for views shrunk")[0]  # (the Python hint: lfsf points shrinks the camera itself)
        raise ValueError(f"{args.result}: {said}" + (" (give the camera of the light fields given to lfsf run)"
                                                      if "this camera is for views" in said else "")) from None
    colours = None
    if args.colour is not None:
        from lfsf.io import read_lightfield

        lf = read_lightfield(args.colour)
        if k > 1:
            lf = lf.downsample(k)
        colours = lf.centre
        if colours.shape[:2] != sf.disp1.shape:
            raise ValueError(f"{args.colour}: its centre view is {colours.shape[1]}×{colours.shape[0]}"
                             + (f" (shrunk {k} times as the result was)" if k > 1 else "")
                             + f", the result {args.result} {sf.disp1.shape[1]}×{sf.disp1.shape[0]}")
    flow3d = points2 - points1
    at_infinity = int((~np.isfinite(points1).all(axis=-1) | ~np.isfinite(points2).all(axis=-1)).sum())
    if at_infinity == sf.disp1.size:
        d = sf.disp1[np.isfinite(sf.disp1)]
        span = f"δ1 spans {float(d.min()):.3g} to {float(d.max()):.3g}, " if d.size else ""
        shrunk = f" (in the result's pixels: the views shrunk {k} times)" if k > 1 else ""
        raise ValueError(f"{args.result}: no point lies in front of this camera ({span}δ0 = {camera.offset:g}"
                         f"{shrunk}, and a point needs δ + δ0 > 0): check δ0, f·b / Z_f for views focused at Z_f")
    if suffix == ".ply":
        from lfsf.io import write_ply

        count = write_ply(args.out, points1, colours, flow3d,
                          comment=f"lfsf points of {args.result}: the t1 centre view's points, flow_* their 3-D "
                                  f"scene flow to t2; camera {camera.as_dict()}")
    else:
        import json

        from lfsf._files import savez_atomic

        extra = {} if sf.occluded is None else {"occluded": sf.occluded}
        savez_atomic(args.out, compressed=True, points1=points1, points2=points2, scene_flow=flow3d,
                     depth1=points1[..., 2], depth2=points2[..., 2], **extra,
                     camera=np.str_(json.dumps(camera.as_dict())))
        count = int(sf.disp1.size - at_infinity)
    z = points1[..., 2][np.isfinite(points1[..., 2])]
    depths = f"depths {float(z.min()):.4g} to {float(z.max()):.4g}" if z.size else "no finite depth"
    _log(args, f"wrote {args.out}: {count} points of {sf.disp1.shape[1]}×{sf.disp1.shape[0]}, {depths} (the "
               f"baseline's unit)" + (f"; {at_infinity} at or beyond infinity (δ + δ0 ≤ 0) left "
                                      + ("out" if suffix == ".ply" else "NaN") if at_infinity else ""))
    if errors is not None:
        e = errors
        print(f"{args.result} against {args.gt} in 3-D (border {border} px, the baseline's unit; the true motions "
              f"{e['motion']:.4g} long on average): scene flow end-point error mean {e['epe3d']:.4g}, median "
              f"{e['epe3d_median']:.4g}"
              + (f", {e['epe3d_noc']:.4g} over the points seen at t2" if "epe3d_noc" in e else "")
              + f"; t1 depth off by {100 * e['depth1_rel']:.3g} % on average; {e['pixels']} px", flush=True)
    return 0


# --- run and demo ----------------------------------------------------------------------------

def _not_estimated_line(where, names) -> str:
    """What a flow-only result's table leaves out, and why (``lfsf eval``, ``run --gt``, ``demo``)."""
    return (f"not evaluated in {where}: {', '.join(names)} (a flow-only result, --preset flow or one "
            "sampling circle: its disparities are zeros, not estimates)")


class _Progress:
    """Progress lines on a terminal (each overwriting the last); silent in logs. The
    estimator's notes (:class:`lfsf.estimate.Note`: an exposure matched or refused, …)
    stay on a line of their own on a terminal and are printed in logs too. Nothing
    with --quiet."""

    def __init__(self, args):
        self.quiet = getattr(args, "quiet", False)
        self.live = sys.stderr.isatty() and not self.quiet
        self.prefix = f"lfsf {getattr(args, 'command', None) or 'run'}: "
        self.t0 = time.perf_counter()
        self.width = 0

    def __call__(self, message: str) -> None:
        from lfsf.estimate import Note

        if self.quiet:
            return
        if not self.live:
            if isinstance(message, Note):
                sys.stderr.write(self.prefix + message + "\n")
                sys.stderr.flush()
            return
        line = f"[{time.perf_counter() - self.t0:6.1f} s] {message}"
        if not isinstance(message, Note):
            # within the terminal's width: a line that wraps is not overwritten by the next
            import shutil

            try:  # (stderr's terminal: stdout may be a file)
                columns = os.get_terminal_size(sys.stderr.fileno()).columns
            except (AttributeError, OSError, ValueError):
                columns = 0
            # (a terminal that reports no width, as under `script` or in some containers, had cut every
            # line to "…": shutil's size is $COLUMNS, stdout's terminal's, else 80; 0 too on Python 3.10)
            columns = (columns or shutil.get_terminal_size().columns or 80) - 1
            line = _cut_to(line, columns, getattr(sys.stderr, "encoding", None))
        sys.stderr.write("\r" + line.ljust(self.width))
        if isinstance(message, Note):  # kept: the next line starts below it
            sys.stderr.write("\n")
            line = ""
        sys.stderr.flush()
        self.width = len(line)

    def done(self) -> None:
        if self.live and self.width:
            sys.stderr.write("\n")
            sys.stderr.flush()


def _cut_to(line: str, columns: int, encoding: str | None) -> str:
    """``line`` as a stream of ``encoding`` shows it (:func:`_as_shown`), cut to ``columns``
    with "…" (or "..." where the stream has no "…"). Counted as shown: on an ASCII
    terminal × is \xd7, four columns, and lines counted in characters had wrapped."""
    shown = _as_shown(line, encoding)
    if len(shown) <= columns:
        return shown
    more = "…" if _as_shown("…", encoding) == "…" else "..."
    if columns <= len(more):
        return shown[:max(columns, 0)]
    pieces, width = [], 0
    for c in line:  # (whole characters: an escape is not cut in two)
        piece = _as_shown(c, encoding)
        if width + len(piece) > columns - len(more):
            break
        pieces.append(piece)
        width += len(piece)
    return "".join(pieces) + more


def _as_shown(text: str, encoding: str | None) -> str:
    """``text`` as a stream of ``encoding`` writes it, characters it lacks backslash-escaped
    (:func:`_usable_streams`' errors)."""
    try:
        return text.encode(encoding or "utf-8", "backslashreplace").decode(encoding or "utf-8", "replace")
    except LookupError:
        return text


def _result_names() -> tuple[str, ...]:
    """What `lfsf run` and `lfsf demo` write into --out (SceneFlow.save with the overview)."""
    from lfsf.batch import RESULT_FILES

    return RESULT_FILES + ("overview.png",)


def _preset_label(args) -> str:
    """What the settings came from, for a log line: "preset 'fast' and run.toml"."""
    config = getattr(args, "config", None)
    if args.preset is not None:
        return f"preset '{args.preset}'" + (f" and {config}" if config else "")
    return f"the settings of {config}" if config else "preset 'paper'"


def _params(args):
    from lfsf.params import Params

    if getattr(args, "config", None):
        # the file's preset = "…" or --preset (both, differing: an error), else paper
        return Params.from_toml(args.config, preset=args.preset)
    # (not `or`: --preset "" is a mistake to name, not the default)
    return Params.preset("paper" if args.preset is None else args.preset)


def _warn_what_config_does_not_repeat(config, device: str) -> None:
    """Warn where a result given as ``--config`` was made in a way that ``lfsf run`` does
    not repeat with its settings: from the previous pair's result (``lfsf batch
    --warm-start``; the run starts from nothing, and had given other maps without a
    word), or on another device (CPU and CUDA round differently)."""
    from lfsf.evaluate import _recorded

    recorded = _recorded(config)
    inputs = recorded.get("inputs") if isinstance(recorded.get("inputs"), dict) else {}
    if inputs.get("warm_start") is True:
        warnings.warn(f"{config} was estimated from the previous pair's result (lfsf batch --warm-start); lfsf run "
                      "starts from nothing, so its maps will differ: run the batch again to repeat it", LfsfWarning)
    made_on = recorded.get("device")
    if isinstance(made_on, str) and (made_on == "cpu") != (device == "cpu"):
        warnings.warn(f"{config} was estimated on {made_on}, this run is on {device}: the CPU and CUDA round "
                      f"differently, and the maps will differ a little (--device {made_on} repeats it)", LfsfWarning)


def cmd_run(args) -> int:
    import numpy as np

    from lfsf.device import resolve_device
    from lfsf.estimate import estimate_scene_flow
    from lfsf.io import check_pair, read_lightfield

    device = resolve_device(args.device)
    params = _params(args)
    if args.config:
        _warn_what_config_does_not_repeat(args.config, device)
    if args.downsample is None:  # (a result given as --config was estimated as it recorded: on views so shrunk)
        from lfsf.evaluate import recorded_downsample

        args.downsample = recorded_downsample(args.config) if args.config else 1
    # before any work; made when the results are written
    output_folder(args.out, create=False, names=_result_names())
    refuse_replacing_inputs(args.out, _result_names(), [args.lf1, args.lf2, args.gt])
    lf1 = read_lightfield(args.lf1)
    # (one light field given twice, stereo: read once)
    lf2 = lf1 if _same_file(args.lf1, args.lf2) else read_lightfield(args.lf2)
    check_pair(lf1, lf2)
    k = args.downsample
    if k > 1 and min(lf1.height, lf1.width) // k < MIN_VIEW_SIZE:
        largest = min(lf1.height, lf1.width) // MIN_VIEW_SIZE
        raise ValueError(f"--downsample {k}: the views of {args.lf1} are {lf1.width}×{lf1.height}, which that "
                         f"leaves at {lf1.width // k}×{lf1.height // k}, under the {MIN_VIEW_SIZE}×{MIN_VIEW_SIZE} "
                         f"px the estimate needs: " + (f"at most --downsample {largest}" if largest > 1 else
                                                      "they are too small to shrink"))
    gt, border = _run_ground_truth(args, lf1, params)
    full_width, full_height = lf1.width, lf1.height
    if args.downsample > 1:
        full = f"{lf1.width}×{lf1.height}"
        lf1, lf2 = (lf1.downsample(args.downsample),) * 2 if lf2 is lf1 else (lf1.downsample(args.downsample),
                                                                               lf2.downsample(args.downsample))
        _log(args, f"lfsf run: views downsampled {full} → {lf1.width}×{lf1.height} (means of {args.downsample}×"
                   f"{args.downsample} px): δ and the flow are in the smaller views' pixels"
                   + (", the ground truth shrunk alike" if gt is not None else ""))
    _warn_memory(args, lf1, lf2, params, device, read=(full_width, full_height))
    rows, cols = lf1.grid
    # (δ and the flow in the shrunk views' pixels: the overview's title says so, as its units)
    shrunk = f" shrunk {args.downsample}x from {full_width}x{full_height}" if args.downsample > 1 else ""
    title = (f"lfsf run: {args.lf1.name} and {args.lf2.name} ({lf1.width}x{lf1.height}{shrunk}, {rows}x{cols} views, "
             f"{_preset_label(args)})" + (f" against {args.gt.name}" if gt is not None else ""))
    # the centre views for the pictures, copied; the light fields handed over to the
    # estimate, which lets them go once it has sampled them (0.8 GB of 3.4 at 1280×960)
    centre1, centre2 = np.array(lf1.centre), np.array(lf2.centre)
    # what the result came from, as lfsf batch records it (the light fields' paths, sizes and
    # times), taken before the work as batch takes it: an input changed meanwhile is not the one read
    from lfsf.batch import Pair, input_record

    inputs = input_record(Pair("run", args.lf1, args.lf2), warm_start=False)
    if args.downsample > 1:
        inputs.update(downsample=args.downsample, views=[full_width, full_height])
    pair = [lf1, lf2]
    del lf1, lf2
    progress = _Progress(args)
    t0 = time.perf_counter()
    try:
        sf = estimate_scene_flow(pair.pop(0), pair.pop(0), params, device=device, progress=progress)
    finally:
        progress.done()
    seconds = time.perf_counter() - t0
    paths = sf.save(args.out, centre1, centre2, gt=gt, title=title, border=border or 0, inputs=inputs)
    _log(args, f"estimated in {seconds:.1f} s on {device}; wrote {len(paths)} files to {args.out}"
               + (" (disp1 and disp2: zeros, not estimated by a flow-only run)" if params.flow_only else ""))
    if gt is not None:  # (after the results are written: an error here loses none of them)
        from lfsf.evaluate import evaluate, format_table

        try:
            errors = evaluate(sf, gt, border=border)
        except ValueError as exc:
            raise ValueError(f"{args.out} against {args.gt}: {exc}") from None
        print(f"{args.out} against {args.gt} (border {border} px"
              + (f"; estimated on views shrunk {args.downsample} times, the ground truth shrunk alike)"
                 f"{_shrunk_units(args.downsample)}"
                 if args.downsample > 1 else ")"))
        print(format_table(errors), flush=True)
        if params.flow_only and any(k in gt for k in ("disp1", "disp2")):
            print(_not_estimated_line(args.out, [k for k in ("disp1", "disp2") if k in gt]), flush=True)
    return 0


#: Host memory of `lfsf run` on the CPU, fitted to its peak RSS (fifty-fifth session): a
#: fixed part and, per pixel, the larger of the levels' buffers (a part, and a part a
#: sample; within 3 % of 0.86, 2.61 and 1.89 GB measured at 640×480 and 1280×960 with 9×9
#: views, `paper` (17 samples) and `fast` (9)) and the light fields while they are read
#: (4 B a value and what reading takes besides; within 15 % of 1.02 GB at 625×434 with 15×15
#: views and 1.15 GB for 1280×960 9×9 with --downsample 2), which the estimate lets go
#: once sampled.
MEMORY_FIXED, MEMORY_PER_PIXEL, MEMORY_PER_SAMPLE, MEMORY_PER_VALUE = 0.3e9, 610.0, 76.0, 5.0


def memory_needed(width: int, height: int, values_per_pixel: int, samples: int) -> float:
    """Bytes of host memory that ``lfsf run`` takes on the CPU, about (:data:`MEMORY_FIXED`):
    ``values_per_pixel`` the light fields' values at a pixel (views × channels, of each
    light field read)."""
    pixels = width * height
    return MEMORY_FIXED + pixels * max(MEMORY_PER_PIXEL + MEMORY_PER_SAMPLE * samples,
                                       MEMORY_PER_VALUE * values_per_pixel)


def _memory_available() -> float | None:
    """MemAvailable of /proc/meminfo in bytes (None where there is none: not Linux)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _warn_memory(args, lf1, lf2, params, device: str, read: tuple[int, int]) -> None:
    """A warning before the work where the estimate will likely need more host memory
    than the machine has free (:func:`memory_needed`; CPU runs), with what the next
    ``--downsample`` would need: its estimate, or the reading of the light fields as
    they are on disk (``read``: their width and height), whichever is more."""
    if not str(device).startswith("cpu"):
        return
    available = _memory_available()
    if available is None:
        return
    per_pixel = sum(lf.views.size // (lf.height * lf.width) for lf in ((lf1,) if lf2 is lf1 else (lf1, lf2)))
    samples = sum(params.samples)
    needed = memory_needed(lf1.width, lf1.height, per_pixel, samples)
    if needed > available:
        k = 2 * (args.downsample or 1)  # (the views here are those already shrunk by --downsample)
        smaller = max(memory_needed(lf1.width // 2, lf1.height // 2, per_pixel, samples),
                      MEMORY_FIXED + read[0] * read[1] * MEMORY_PER_VALUE * per_pixel)
        print(f"lfsf run: warning: this estimate needs about {needed / 1e9:.1f} GB of memory, and "
              f"{available / 1e9:.1f} GB are free: it may run out (--downsample {k}: about {smaller / 1e9:.1f} GB)",
              file=sys.stderr, flush=True)


#: The smallest views the estimator takes (px along the shorter side): what --downsample
#: may leave.
MIN_VIEW_SIZE = 8


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file or folder (False where either cannot be read)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def _run_ground_truth(args, lf1, params):
    """``lfsf run --gt``: the ground truth and its border (:func:`lfsf.evaluate.load_ground_truth`),
    read and checked against the light field's view size before any work; (None, None)
    without the option."""
    if args.gt is None:
        return None, None
    from lfsf.evaluate import evaluate, load_ground_truth

    gt, border = load_ground_truth(args.gt)
    wrong = next(((k, a.shape) for k, a in gt.items() if a.shape != (lf1.height, lf1.width)), None)
    if wrong:
        k, s = wrong
        raise ValueError(f"{args.gt}: '{k}' is {s[1]}×{s[0]}, and the light field's views {args.lf1} are "
                         f"{lf1.width}×{lf1.height}")
    k = args.downsample
    if k > 1:  # (a factor that leaves views too small is refused before: cmd_run)
        from lfsf.evaluate import downsample_border, downsample_truth

        gt, border = downsample_truth(gt, k), downsample_border(border, k)  # (the truth of the smaller views)
    # the evaluation that will follow, tried now on the truth itself as the estimate of what
    # the settings estimate: a border that leaves no pixel, or nothing in common (a flow-only
    # run against δ1 alone), refused before the work rather than after it
    estimated = ("u", "v") if params.flow_only else ("disp1", "disp2", "u", "v")
    if params.flow_only and not any(name in gt for name in estimated):  # (the general message spoke of disp2.pfm)
        raise ValueError(f"{args.gt}: cannot score this run against it: it holds {', '.join(sorted(gt))}, and a "
                         "flow-only run (one circle) estimates u and v; leave --gt out, or give a flow truth")
    try:
        evaluate({k: gt[k] for k in estimated if k in gt}, gt, border=border)
    except ValueError as exc:
        raise ValueError(f"{args.gt}: cannot score this run against it: {exc}") from None
    return gt, border


def cmd_demo(args) -> int:
    from lfsf import synth
    from lfsf.device import resolve_device
    from lfsf.estimate import estimate_scene_flow, load_kernels
    from lfsf.evaluate import SYNTH_BORDER, evaluate, format_table
    from lfsf.kernels import render

    device = resolve_device(args.device)
    params = _params(args)
    synth.get_scene(args.scene)
    synth.check_render(args.size, args.grid, colour=args.colour)  # before any work
    rows, cols = args.grid
    if params.circles > 1 and params.grid_radius((rows, cols)) <= 0:  # (refused by the estimate, after the render)
        raise ValueError(f"--grid {rows}x{cols}: no room for the sampling circles (M = {params.circles}, N = "
                         f"{list(params.samples)}); on a rig of one row, --config FILE.toml with circles = 2 and "
                         "samples = [1, 2] samples along it, and --preset flow estimates the flow alone")
    width, height = args.size
    if min(width, height) <= 2 * SYNTH_BORDER:
        raise ValueError(f"--size {width} {height}: the demo's errors leave out a border of {SYNTH_BORDER} px; "
                         f"give at least {2 * SYNTH_BORDER + 1} px each way")
    out = output_folder(args.out, create=False, names=_result_names())
    _say(args, f"lfsf demo: scene '{args.scene}', {width}×{height}, {args.grid[0]}×{args.grid[1]} "
               f"{'RGB ' if args.colour else ''}views, {_preset_label(args)}, on {device}")
    # the renderer's kernels and the estimator's compiled together (on a cold kernel cache)
    compiled = load_kernels(device, extra=[render], say=lambda line: _say(args, line))
    if compiled:
        _say(args, compiled)
    t0 = time.perf_counter()
    lf1, lf2, gt = synth.render_scene(args.scene, size=(width, height), grid=args.grid, colour=args.colour,
                                      device=device)
    t_render = time.perf_counter() - t0
    progress = _Progress(args)
    t0 = time.perf_counter()
    try:
        sf = estimate_scene_flow(lf1, lf2, params, device=device, progress=progress)
    finally:
        progress.done()
    t_est = time.perf_counter() - t0
    errors = evaluate(sf, gt, border=SYNTH_BORDER)  # (flow only: the flow alone)
    _say(args, f"rendered in {t_render:.1f} s, estimated in {t_est:.1f} s")
    print(format_table(errors), flush=True)
    if params.flow_only:
        print(_not_estimated_line(out, ["disp1", "disp2"]), flush=True)
    else:  # the same in 3-D, through the camera that rendered the scene (lfsf points)
        from lfsf.camera import Camera, scene_flow_errors

        e = scene_flow_errors(sf, gt, Camera.from_truth(gt), border=SYNTH_BORDER)
        print(f"3-D scene flow, in the scene's units (its true motions {e['motion']:.4f} long on average): end-point "
              f"error mean {e['epe3d']:.4f}, median {e['epe3d_median']:.4f}; t1 depth off by "
              f"{100 * e['depth1_rel']:.2f} % on average", flush=True)
    # the overview with the ground truth and the errors, in the one set of results
    sf.save(out, lf1.centre, lf2.centre, gt=gt, border=SYNTH_BORDER,
            title=f"lfsf demo: '{args.scene}' ({width}x{height}, {args.grid[0]}x{args.grid[1]} "
                  f"{'RGB ' if args.colour else ''}views, {_preset_label(args)})")
    _say(args, f"wrote {out / 'overview.png'} and the results (disp1.pfm, disp2.pfm, flow.flo, sceneflow.npz, "
               f"disp1.png, disp2.png, flow.png) to {out}")
    return 0


def _say(args, message: str) -> None:
    """A line of the demo's report on stdout (not with --quiet; the error table always)."""
    if not getattr(args, "quiet", False):
        print(message, flush=True)


# --- batch ---------------------------------------------------------------------------------

def cmd_batch(args) -> int:
    from lfsf import batch
    from lfsf.device import resolve_device

    params = _params(args)
    if args.config:
        from lfsf.evaluate import recorded_downsample

        k = recorded_downsample(args.config)
        if k > 1:  # (lfsf run --config R shrinks the views as R's were; batch has no --downsample)
            warnings.warn(f"{args.config} was estimated on views downsampled by {k} (lfsf run --downsample {k}); "
                          "lfsf batch takes its settings alone and estimates the views at full size", LfsfWarning)
    if args.scheduler is not None and args.workers is not None:
        raise ValueError(f"--workers {args.workers} sets the processes of a local cluster; with --scheduler the "
                         "scheduler's own workers run the pairs: give one of the two")
    workers = args.workers or 1
    output_folder(args.out, create=False)  # made once there is a cluster to write into it
    if args.scheduler is not None:
        batch.check_scheduler_address(args.scheduler)
    elif args.device or os.environ.get("LFSF_DEVICE"):
        resolve_device(args.device)  # a device this machine lacks (or $LFSF_DEVICE's): one error before any work
    pairs = batch.pairs_from_sources(args.sources, out=args.out)
    batch.check_outputs(pairs, args.out)  # before the first line of the run
    batch.check_warm_start(pairs, args.warm_start)
    batch.check_dask(workers, args.scheduler)  # before the first line of the run
    dask = batch._dask_problem()
    where = (f"the Dask scheduler at {args.scheduler}" if args.scheduler
             else f"a local Dask cluster of {workers} process{'es' if workers > 1 else ''}"
             if dask is None else f"this process (Dask is {dask})")
    count = f"{len(pairs)} pair{'s' if len(pairs) != 1 else ''}"
    _log(args, f"lfsf batch: {count} to {args.out}, {_preset_label(args)}, on {where}"
               + (", each pair of a folder's frames starting from the one before" if args.warm_start else ""))
    bar = batch.ProgressBar(len(pairs), quiet=args.quiet)
    summary = batch.run_batch(pairs, args.out, params, workers=workers, scheduler=args.scheduler,
                              device=args.device, warm_start=args.warm_start, progress=bar)
    print(f"lfsf batch: {summary.describe()}")
    if summary.failed:
        print(f"lfsf batch: the failed pairs and why are in {Path(args.out) / 'failed.csv'}")
        return 1
    return 0


# --- decode --------------------------------------------------------------------------------

def cmd_decode(args) -> int:
    from lfsf.decode import decode_files
    from lfsf.device import resolve_device

    device = resolve_device(args.device)
    output_folder(args.out, create=False)
    t0 = time.perf_counter()
    lf, report = decode_files(args.raw, args.white, args.out, views=args.views, bayer=args.bayer,
                              flip=args.flip, device=device)
    lattice = lf.meta["lattice"]
    _log(args, f"{lattice.describe()}")
    rows, cols = lf.grid
    _log(args, f"decoded {rows}×{cols} views of {lf.width}×{lf.height} pixels"
               f"{' (RGB)' if lf.is_colour else ''} in {time.perf_counter() - t0:.1f} s on {device}; "
               f"wrote {args.out} (HCI layout), {args.out / 'views.npz'} and {args.out / 'decode.json'}")
    if not lf.is_colour and report["bayer"] is None and (args.bayer or "").lower() != "none":
        # (a mosaic decoded as grey shows the filters' pattern in every view, without a word)
        _log(args, "grey: no Bayer pattern was given (--bayer) or found in the file's metadata; "
                   "if the sensor has colour filters, decode again with --bayer RGGB, GRBG, GBRG or BGGR")
    return 0


# --- bench ---------------------------------------------------------------------------------

@_with_json_report
def cmd_bench(args) -> list:
    from lfsf import bench
    from lfsf.device import resolve_device

    device = resolve_device(args.device)
    if args.inputs and args.kind != "kernels":
        raise ValueError(f"--inputs applies to `lfsf bench kernels`, not to {args.kind}")
    size = tuple(args.size) if args.size else None
    if size:
        from lfsf.synth import check_render

        check_render(size, 9)  # the benches render 9×9 views
    if size and args.kind in ("pipeline", "peers"):
        from lfsf.evaluate import SYNTH_BORDER

        if min(size) <= 2 * SYNTH_BORDER:
            raise ValueError(f"--size {size[0]} {size[1]}: the errors leave out a border of {SYNTH_BORDER} px; "
                             f"give at least {2 * SYNTH_BORDER + 1} px each way")
    say = (lambda m: None) if args.quiet else (lambda m: _log(args, f"lfsf bench {args.kind}: {m}"))
    if args.kind == "pipeline":
        rows = bench.bench_pipeline(size or (640, 480), device, repeats=args.repeats or 3, progress=say)
    elif args.kind == "kernels":
        rows = bench.bench_kernels(size or (640, 480), device, repeats=args.repeats or 20, progress=say,
                                   inputs=args.inputs or "scene")
    else:
        rows = bench.bench_peers(size or (640, 480), device, repeats=args.repeats or 3, progress=say)
    print(bench.format_rows(args.kind, rows))
    # (the pipeline's rows hold each setting's own peak; the process's since the last
    # setting began would be the last one's alone)
    peaks = [r["peak_rss_mb"] for r in rows if r.get("peak_rss_mb") is not None]
    process_peak = bench.peak_rss_mb()
    peak = (f"{max(peaks):.0f} MB (the largest setting's)" if args.kind == "pipeline" and peaks
            else "unknown (this system does not tell it)" if process_peak is None else f"{process_peak:.0f} MB")
    print(f"peak RSS {peak}")
    print(f"machine: {_machine()}")
    return rows


def _machine() -> str:
    """The machine in a line (:func:`lfsf.bench.machine_record`): the CPU's model, its
    CPUs, Python's version."""
    from lfsf.bench import machine_record

    m = machine_record()
    return f"{m['cpu']}, {m['cpus']} CPUs, Python {m['python']}"


def _device_options(p) -> None:
    """--device and --quiet, which every command that computes takes."""
    p.add_argument("--device", type=_device_name,
                   help="cpu or cuda:N (default: $LFSF_DEVICE, else cuda:0 if present, else cpu)")
    p.add_argument("--quiet", action="store_true", help="no progress messages")


def _estimator_options(p) -> None:
    p.add_argument("--preset",
                   help="paper (17 views), fast, lytro, or flow (optical flow of the centre views alone) "
                        "(default paper, or the --config file's preset)")
    p.add_argument("--config", type=_input_name, help="TOML file setting any parameter of lfsf.Params, or a result "
                   "(its folder or sceneflow.npz) whose recorded settings to use again")
    _device_options(p)


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="lfsf", description="Scene flow from light fields (Heber & Pock, GCPR 2014).")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=ArgumentParser)

    p = sub.add_parser("synth", help="render a synthetic light-field pair with exact ground truth",
                       description="Render SCENE at t1 and t2 into DIR/lf1.npz, DIR/lf2.npz and its "
                                   "ground truth DIR/gt.npz.")
    p.add_argument("scene", nargs="?", help="scene name (see --list)")
    p.add_argument("--list", action="store_true", help="list the scenes and exit")
    p.add_argument("--out", type=_folder_name, help="output folder")
    p.add_argument("--size", nargs=2, type=_size, metavar=("W", "H"), default=(640, 480),
                   help="view size in pixels (default 640 480)")
    p.add_argument("--grid", type=_grid, default=(9, 9), metavar="N|ROWSxCOLS",
                   help="N×N views, or ROWSxCOLS: 1x9 a rig of one row (default 9)")
    p.add_argument("--supersample", type=_positive, default=2, metavar="K",
                   help="K×K rays per pixel (default 2)")
    p.add_argument("--colour", action="store_true", help="RGB views (default grey)")
    p.add_argument("--frames", type=int, default=2, metavar="K",
                   help="K > 2: a sequence moving at a constant rate, DIR/frames/f000.npz … and the ground truth "
                        "of each pair DIR/gt/f000.npz … (default 2: DIR/lf1.npz, DIR/lf2.npz, DIR/gt.npz)")
    p.add_argument("--noise", type=float, default=0.0, metavar="SIGMA",
                   help="Gaussian sensor noise of this standard deviation (intensities in [0, 1]; 0 to 1) on "
                        "every view, independent per frame (default 0)")
    p.add_argument("--images", type=Path, metavar="FOLDER",
                   help="photographs instead of the solid textures: every object shows one of FOLDER's images "
                        "(PNG, JPEG, TIFF), drawn with --image-seed; the geometry and ground truth stay the scene's")
    p.add_argument("--image-seed", type=int, default=None, metavar="N",
                   help="with --images: the draw of each object's image and scale (default 0)")
    p.add_argument("--preview", action="store_true", help="also write DIR/preview.png of the ground truth")
    _device_options(p)
    p.set_defaults(func=cmd_synth)

    p = sub.add_parser("eval", help="errors of a result against ground truth",
                       description="Print MSE per variable, flow end-point error, disparity "
                                   "BadPix(0.07) and MSE×100 over valid pixels; where the result and a gt.npz "
                                   "both mark the points not seen at t2 ('occluded'), the result's mask's "
                                   "precision, recall and F1.")
    p.add_argument("result", type=Path, help="a folder written by 'lfsf run', or a .npz/.pfm/.flo")
    p.add_argument("gt", type=Path, help="gt.npz of 'lfsf synth' or an HCI gt_disp_lowres.pfm")
    p.add_argument("--border", type=int, default=None,
                   help="pixels left out at each edge (default 15 for a .pfm, as the HCI benchmark; 8 for gt.npz; "
                        "divided by K, rounded up, for a result of 'lfsf run --downsample K')")
    p.add_argument("--json", type=_report_name, help="also write the figures to this JSON file ('-': to stdout, and "
                   "the table to stderr)")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("points", help="3-D points and scene flow of a result, for a calibrated camera",
                       description="Turn a result's δ1, δ2 and flow into the 3-D points of the t1 centre view at "
                                   "t1 and t2 and their difference, the 3-D scene flow (MODEL.md §7: Z = f·b / "
                                   "(δ + δ0), in the centre camera's frame, x right, y down, z forward, in the "
                                   "unit of b). OUT.ply: a point cloud of the t1 points with the flow as "
                                   "flow_x, flow_y, flow_z (the points whose t1 or t2 point lies at or beyond "
                                   "infinity left out); OUT.npz: the maps points1, points2, scene_flow, depth1, "
                                   "depth2 (NaN there), occluded and the camera (JSON).")
    p.add_argument("result", type=_input_name, help="a folder written by 'lfsf run' (or its sceneflow.npz)")
    p.add_argument("--camera", nargs="+", required=True, metavar=("F|FILE", "B"),
                   help="the centre view's focal length f (px), the baseline b between neighbouring views and the "
                        "disparity offset δ0 of the focus plane (default 0: views aligned at infinity; f·b / Z_f "
                        "for views focused at Z_f), or a file recording them: a gt.npz of 'lfsf synth' or an HCI "
                        "parameters.cfg (or its folder); of the full views, for a result of 'lfsf run "
                        "--downsample K' too")
    p.add_argument("--principal", nargs=2, type=float, metavar=("CX", "CY"),
                   help="the principal point in px of the full views (default: their centre)")
    p.add_argument("--colour", type=_input_name, metavar="LF",
                   help="colour the .ply's points by this light field's centre view (the t1 one)")
    p.add_argument("--out", type=_file_name, required=True, help="OUT.ply or OUT.npz")
    p.add_argument("--gt", type=_input_name, metavar="GT",
                   help="a gt.npz of 'lfsf synth': also print the 3-D scene flow's end-point error and the t1 "
                        "depth's relative error against its points (through the same camera; valid pixels, an "
                        "8-px border, shrunk with the views of a result of 'lfsf run --downsample K')")
    p.add_argument("--quiet", action="store_true", help="no messages (the errors of --gt still print)")
    p.set_defaults(func=cmd_points)

    p = sub.add_parser("run", help="estimate scene flow from two light fields",
                       description="Estimate δ1, δ2 and the flow of the centre view from light fields at t1 and "
                                   "t2; writes disp1.pfm, disp2.pfm, flow.flo, sceneflow.npz and pictures. Warns "
                                   "before the work where the estimate will likely need more memory than is free "
                                   "(README, Large views).")
    p.add_argument("lf1", type=Path, help="light field at t1 (folder of views or .npz)")
    p.add_argument("lf2", type=Path, help="light field at t2")
    p.add_argument("--out", type=_folder_name, required=True, help="output folder")
    p.add_argument("--gt", type=Path, metavar="GT",
                   help="ground truth (gt.npz of 'lfsf synth', or an HCI gt_disp_lowres.pfm): print the errors as "
                        "'lfsf eval' does and add the truth and the errors to overview.png")
    p.add_argument("--downsample", type=_positive, default=None, metavar="K",
                   help="estimate on views K times smaller, each pixel the mean of K×K (a quick look at large "
                        "views); the results, and δ and the flow in them, are in the smaller views' pixels, and "
                        "--gt is shrunk alike, its border too; the result records K, which lfsf eval and "
                        "--config RESULT use (default 1: the views as they are; with --config RESULT, its K)")
    _estimator_options(p)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("decode", help="decode a raw lenslet image into sub-aperture views",
                       description="Calibrate the micro-lens lattice from WHITE alone, devignette and demosaic RAW, "
                                   "and resample it into N×N views: DIR in the HCI layout, DIR/views.npz and "
                                   "DIR/decode.json (the lattice). RAW and WHITE: 16-bit PNG/TIFF, Lytro "
                                   ".lfr/.lfp/.raw, or any raw format rawpy reads.")
    p.add_argument("raw", type=Path, help="raw lenslet image")
    p.add_argument("--white", type=Path, required=True, help="white image of the same camera")
    p.add_argument("--out", type=_folder_name, required=True, help="output folder")
    p.add_argument("--views", type=_positive, metavar="N",
                   help="N×N views spanning one lens pitch, at most the pitch rounded up (default: the largest "
                        "odd N not above the pitch)")
    p.add_argument("--bayer", type=lambda text: "none" if text.lower() == "none" else text.upper(),
                   choices=("RGGB", "BGGR", "GRBG", "GBRG", "none"),
                   metavar="{RGGB,BGGR,GRBG,GBRG,none}",
                   help="Bayer pattern of a colour sensor (default: from the file's metadata; none: grey)")
    p.add_argument("--flip", action="store_true", help="negate the angular axes (optics that invert micro-images)")
    _device_options(p)
    p.set_defaults(func=cmd_decode)

    p = sub.add_parser("demo", help="render a built-in scene, estimate it, print its errors",
                       description="Render a synthetic scene with exact ground truth, estimate its scene flow, "
                                   "print the error table and write an overview picture.")
    p.add_argument("--scene", default="paper", help="scene name (see 'lfsf synth --list'; default paper)")
    p.add_argument("--size", nargs=2, type=_size, metavar=("W", "H"), default=(320, 240),
                   help="view size (default 320 240; at least 17 each way: the errors leave out an 8-px border)")
    p.add_argument("--grid", type=_grid, default=(9, 9), metavar="N|ROWSxCOLS",
                   help="N×N views, or ROWSxCOLS: 1x9 a rig of one row (default 9)")
    p.add_argument("--colour", action="store_true",
                   help="RGB views (default grey): the estimate then also takes δ1's diffusion tensor from the "
                        "colours (Params.colour_tensor) and snaps δ1 and δ2 to the colour edges "
                        "(Params.colour_median_radius)")
    p.add_argument("--out", type=_folder_name, default=Path("lfsf-demo"), help="output folder (default ./lfsf-demo)")
    _estimator_options(p)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("batch", help="estimate many pairs, on a local or remote Dask cluster",
                       description="Estimate every pair of manifests (CSV lines t1,t2[,name]) and folders of frames "
                                   "(consecutive pairs); each pair's results go to DIR/NAME/ as for 'lfsf run'. "
                                   "Complete results are skipped; failed pairs are listed in DIR/failed.csv and the "
                                   "exit status is then 1.")
    p.add_argument("sources", nargs="+", type=Path, metavar="SOURCE", help="a manifest CSV or a folder of frames")
    p.add_argument("--out", type=_folder_name, required=True, help="output folder")
    p.add_argument("--workers", type=_positive, default=None, metavar="N",
                   help="processes of the local Dask cluster (default 1; without Dask, 1 runs in this process; "
                        "not with --scheduler)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("--warm-start", action="store_true",
                   help="start each pair of a folder of frames from the previous pair's result (pairs run in "
                        "order; a manifest's pairs stand alone)")
    _estimator_options(p)
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser("bench", help="benchmarks: kernels, the whole pipeline, or the peers",
                       description="Time repeated runs after a warm-up and print median and spread; --json writes "
                                   "the rows. pipeline: the estimator per setting (the paper's first) with per-stage "
                                   "seconds and peak RSS; kernels: the hot kernels' bandwidth against a plain copy; "
                                   "peers: lfsf flow-only (the paper's schedule), lfsf's flow preset, lfsf scene flow, OpenCV "
                                   "DualTVL1 and skimage TV-L1 with EPE.")
    p.add_argument("kind", nargs="?", default="pipeline", choices=("kernels", "pipeline", "peers"),
                   help="what to measure (default pipeline)")
    p.add_argument("--size", nargs=2, type=_size, metavar=("W", "H"),
                   help="view size (default 640 480; pipeline and peers: at least 17 each way, their errors leave "
                        "out an 8-px border)")
    p.add_argument("--repeats", type=_repeats, help="timed runs, at most 1000 (default 3; kernels 20)")
    p.add_argument("--inputs", choices=("scene", "random"),
                   help="kernels: what they run on, the arrays of a rendered scene's last warp (default) or "
                        "random views and unknowns (a worst case: every pixel takes the occlusion tests' path)")
    p.add_argument("--json", type=_report_name, help="also write the rows to this JSON file ('-': to stdout, and the "
                   "tables to stderr)")
    _device_options(p)
    p.set_defaults(func=cmd_bench)
    return parser


def _version() -> str:
    from lfsf import __version__

    return __version__


def main(argv=None) -> int:
    # Ctrl-C while the parser is being built is 'interrupted' and 130 as later, not a
    # traceback (only Python's own start-up and this module's small imports come before)
    try:
        parser = build_parser()
        args, extra = parser.parse_known_args(argv)
        if extra:
            # after the command, named by the command's own parser ("lfsf run: error: …", lfsf run
            # --help); before it (lfsf --quiet demo), by lfsf's
            given = list(sys.argv[1:] if argv is None else argv)
            at = given.index(args.command) if args.command in given else len(given)
            commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
            after = all(token in given[at + 1:] for token in extra)
            owner = commands.get(args.command, parser) if after else parser
            owner.error(f"unrecognized arguments: {' '.join(extra)}")
    except KeyboardInterrupt as exc:  # (or SIGTERM, SIGHUP: entry's handlers raise Terminated)
        from lfsf._errors import _stopped

        return _stopped("lfsf", exc)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_BAD_INPUT
    prog = f"lfsf {args.command}"
    stdout, stderr = sys.stdout, sys.stderr
    try:
        sys.stdout, sys.stderr = _PipeSafe(stdout, "stdout"), _PipeSafe(stderr, "stderr")
        with warnings.catch_warnings():  # (restores the default display on the way out)
            # a warning is one line like every other message, not Python's file:line and source
            warnings.showwarning = lambda message, *_rest, **_kw: print(f"{prog}: warning: {message}",
                                                                        file=sys.stderr)
            return run_script(lambda: args.func(args), prog=prog)
    finally:
        sys.stdout, sys.stderr = stdout, stderr


class _PipeSafe:
    """stdout (stderr) for a command: where its reader has gone (``lfsf demo | head -1``,
    ``lfsf batch … 2>&1 | head -1``), what is printed later is dropped and the command
    goes on to write its files, instead of ending in "[Errno 32] Broken pipe" with the
    results thrown away; so where the terminal has hung up (EIO), and on any failure of
    stderr. The stream's file descriptor then points at /dev/null, so that the
    interpreter's last flush is quiet. Any other failure to write stdout (a full disk) is
    an OSError that names it."""

    def __init__(self, stream, name: str):
        self._stream = stream
        self._name = name

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as exc:
            self._failed(exc)
            return len(text)

    def flush(self):
        try:
            self._stream.flush()
        except OSError as exc:
            self._failed(exc)

    def _failed(self, exc: OSError):
        """A reader gone (EPIPE), a terminal hung up (EIO): dropped from now on, as is
        anything on stderr, whose diagnostics must not end the work; any other failure of
        stdout (a full disk) raises, naming it."""
        if isinstance(exc, BrokenPipeError) or exc.errno == errno.EIO or self._name == "stderr":
            self._drop()
            return
        raise OSError(exc.errno, exc.strerror or str(exc), f"<{self._name}>") from None

    def _drop(self):
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self._stream.fileno())
            os.close(devnull)
        except (OSError, ValueError):  # no descriptor (a captured stream): nothing to point elsewhere
            pass

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _usable_streams() -> None:
    """stdout and stderr as a command can use them: /dev/null in the place of one that is
    closed (``>&-``, ``2>&-``: the first print, or Warp's start, which duplicates
    descriptor 2, had ended in a traceback or silently), and text their encoding lacks
    written as escapes (an ASCII stdout: the "×" of "MSE×100" had ended lfsf eval with
    status 2, its report unwritten)."""
    for fd, name in ((1, "stdout"), (2, "stderr")):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_WRONLY)
            if null != fd:
                os.dup2(null, fd)  # (inheritable, as a standard stream is)
                os.close(null)
            else:  # (it took the closed descriptor's number, not inheritable: a child would lack it)
                os.set_inheritable(fd, True)
            setattr(sys, name, open(fd, "w", closefd=False))
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, ValueError):
            stream.reconfigure(errors="backslashreplace")


def entry() -> None:  # pragma: no cover - the installed command; tests call main()
    """The ``lfsf`` command (and ``python -m lfsf``): :func:`main`'s status as the exit
    status. After Ctrl-C (or SIGTERM, SIGHUP) the process ends at once, once "interrupted"
    (or "terminated", "hung up") is printed: the interpreter's shutdown would wait for the thread pool's
    bands still running and collect objects the interrupt left half made, and either could
    print a traceback after that line (imageio's PNG writer, cut off while being set up,
    did in 1 of 20 interrupted runs)."""
    import signal

    from lfsf._errors import Terminated, _stopped, ending_signals

    _usable_streams()

    def late(signum, frame):
        # as the command's own handlers would, where theirs have been put back and it has not
        # yet ended (the default had killed the process by the signal, without a word)
        raise KeyboardInterrupt if signum == signal.SIGINT else Terminated(signum)

    from lfsf._errors import quiet_interrupts_in_finalisers

    # (what the command leaves is freed after its own hooks are gone: a second Ctrl-C there)
    sys.unraisablehook = quiet_interrupts_in_finalisers
    handled = [s for s in (signal.SIGINT, *ending_signals()) if signal.getsignal(s) not in (signal.SIG_IGN, None)]
    for s in handled:
        with contextlib.suppress(OSError, ValueError):
            signal.signal(s, late)
    try:
        status = main()
    except KeyboardInterrupt as exc:  # (after the command's own handling)
        status = _stopped("lfsf", exc)
    if status in (EXIT_INTERRUPTED, EXIT_TERMINATED, EXIT_HUNG_UP):
        _exit_now(status)
    # the command has ended and said so: a signal during the interpreter's shutdown ends
    # the process at once with the command's status while it joins the thread pool (about
    # 0.25 s), and is ignored after that (at exit). It had printed a traceback after the
    # results' line, or turned status 0 into 130; and a handler in Python is undone late
    # in the shutdown, where a thread of a native library (a BLAS pool's) then took the
    # signal with the default action: the process died by it.
    def ignored():
        for s in handled:
            with contextlib.suppress(OSError, ValueError):
                signal.signal(s, signal.SIG_IGN)

    for s in handled:
        with contextlib.suppress(OSError, ValueError):
            signal.signal(s, lambda signum, frame: _exit_now(status))
    atexit.register(ignored)  # (atexit runs once the threads are joined)
    sys.exit(status)


def _exit_now(status: int) -> None:
    """End the process with ``status`` at once, what is printed flushed first and Warp's
    temporary folders removed (its own removal, at the interpreter's exit, is skipped)."""
    try:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        from lfsf.device import remove_warp_temporaries

        remove_warp_temporaries()
    finally:  # (a second Ctrl-C meanwhile: the exit all the same)
        os._exit(status)


if __name__ == "__main__":  # pragma: no cover
    entry()
