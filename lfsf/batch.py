"""Batch runs: many light-field pairs, in this process or on a Dask cluster (``lfsf batch``).

Each pair is one task that loads its two light fields, estimates, and writes its results
to ``OUT/NAME/`` as ``lfsf run`` does. Nothing is shared between tasks but the output
folder:

* a task writes into a hidden temporary folder ``OUT/.NAME.part-HOST-PID-…`` and renames
  it to ``OUT/NAME`` only when every file is there (an earlier result moved aside first),
  so a killed run never leaves a half-written result, and a result folder that exists is
  complete; the temporary folders of gone processes are removed, another batch's into
  the same folder are left to it;
* a re-run skips the pairs whose result folder is complete and was estimated with the
  same settings, from the same input files (the paths, sizes and modification times its
  sceneflow.npz records) and with the same ``warm_start``; it estimates again, and
  replaces, any other result, incomplete ones and those whose sceneflow.npz does not
  read;
* a pair that fails (bad input, an error in the estimate) is reported with its reason
  and the others go on; a worker process that dies in the middle of a task is replaced
  and the task runs again elsewhere (Dask retries it);
* with ``warm_start``, the pairs of one sequence run in order and each starts from the
  previous pair's result (:func:`lfsf.estimate.predict_next`), read back from its folder.

Execution is on Dask distributed (the ``batch`` extra): a local cluster of ``workers``
processes, or a running scheduler. Without Dask, one worker runs in this process.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import glob
import io as _io
import os
import re
import shutil
import sys
import time
import traceback
import uuid
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from lfsf._errors import _FULL, BAD_INPUT_ERRORS, DependencyError, MachineError, whole
from lfsf._files import (SET_PREFIX, _host, dead_set, file_name, gone, read_capped, replace, resolved,
                         write_bytes_atomic)

#: The files of a complete result (those :meth:`lfsf.estimate.SceneFlow.save` writes
#: without the centre views; with them, ``overview.png`` too, which results of earlier
#: versions' batches lack).
RESULT_FILES = ("disp1.pfm", "disp2.pfm", "flow.flo", "sceneflow.npz", "disp1.png", "disp2.png", "flow.png")
#: Light-field files a frame folder may hold (besides sub-folders of views).
FRAME_SUFFIXES = (".npz",)
#: Names in a folder of frames that are no frames: the ground truth that ``lfsf synth``
#: writes beside its light fields (``gt.npz`` beside ``lf1.npz`` and ``lf2.npz``; ``gt/``
#: beside ``frames/`` with ``--frames``).
GROUND_TRUTH_NAMES = ("gt", "gt.npz")
INSTALL_HINT = "pip install 'dask[distributed]' (or pip install -e '.[batch]' in the lfsf checkout)"


@dataclass(frozen=True)
class Pair:
    """One task: light fields ``t1`` and ``t2``, results to ``OUT/name``. ``previous``
    names the pair before it in the same sequence (for warm starts); ``sequence``: the
    pair is one of a folder of frames (its first has no previous one), not a manifest's."""

    name: str
    t1: Path
    t2: Path
    previous: str | None = None
    sequence: bool = False


@dataclass
class Outcome:
    """What became of one pair: ``status`` is ``done``, ``skipped`` or ``failed``."""

    name: str
    status: str
    seconds: float = 0.0
    reason: str = ""
    warm: bool = False
    #: The estimator's notes on the pair (:class:`lfsf.estimate.Note`: an exposure matched
    #: or refused, the views' gains matched, …), to be reported with it.
    notes: tuple[str, ...] = ()
    #: Its warnings (:class:`lfsf.estimate.Warned`: views laid out otherwise, float views
    #: far outside [0, 1]), reported even with ``quiet``.
    warned: tuple[str, ...] = ()


@dataclass
class Summary:
    """A whole batch: one :class:`Outcome` per pair, in the order of the pairs."""

    outcomes: list[Outcome] = field(default_factory=list)
    seconds: float = 0.0

    def count(self, status: str) -> int:
        return sum(o.status == status for o in self.outcomes)

    @property
    def failed(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    def describe(self) -> str:
        done = [o.seconds for o in self.outcomes if o.status == "done"]
        per_pair = f", {np.median(done):.1f} s per pair (median)" if done else ""
        replaced = sum(o.status == "done" and o.reason == REPLACED for o in self.outcomes)
        again = f" ({replaced} over an earlier result: {REPLACED_WHICH})" if replaced else ""
        return (f"{self.count('done')} done{again}, {self.count('skipped')} skipped (complete), "
                f"{self.count('failed')} failed in {self.seconds:.1f} s{per_pair}")


# --- sources ----------------------------------------------------------------------------------

def pairs_from_sources(sources: Sequence[str | os.PathLike] | str | os.PathLike,
                       out: str | os.PathLike | None = None) -> list[Pair]:
    """The pairs named by manifests and frame folders (``sources``: a list of them, or
    one).

    A manifest is a CSV file with ``t1,t2[,name]`` per line (a header line whose first
    two cells are ``t1,t2`` is optional; blank lines and lines starting with ``#`` are
    left out; relative paths are relative to the manifest's folder; the name defaults to
    t1's stem). A folder holds one light field per frame (a sub-folder of views or a
    ``.npz``; not ``gt.npz`` or ``gt/``, :data:`GROUND_TRUTH_NAMES`), sorted by name;
    consecutive frames make the pairs, named after their first frame, each the successor
    of the one before. Where names given by default collide (two folders of frames named
    alike, ``A/lf1.npz`` and ``B/lf1.npz``), the folder tells them apart: ``A-lf1``,
    ``B-lf1`` (:func:`_told_apart`). Paths come back absolute: on a cluster,
    every worker must see them under the same names (a shared file system). ``out``, the
    batch's output folder, is no frame: where it lies inside a folder of frames it is
    left out of that folder's frames (a re-run would take the results for a frame).

    Raises
    ------
    FileNotFoundError
        A source that does not exist.
    ValueError
        A malformed manifest, a folder with fewer than two frames, two pairs with one name,
        ``out`` the folder of frames itself.
    """
    if isinstance(sources, (str, os.PathLike)):  # (one path: a str had been read a character at a time)
        sources = [sources]
    if not sources:
        raise ValueError("give at least one manifest CSV or folder of frames")
    out = None if out is None else Path(out).absolute()
    groups: list[tuple[list[Pair], list[bool] | None]] = []
    given: set[Path] = set()
    for source in sources:
        path = file_name(source, "a manifest or a folder of frames").absolute()  # (workers elsewhere see the same)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such manifest or folder")
        if resolved(path) in given:
            raise ValueError(f"{path}: given twice; every pair would be estimated twice into one folder")
        given.add(resolved(path))
        if path.is_dir() and out is not None and _within(path, out):
            raise ValueError(f"{out}: the output folder must not be the folder of frames {path} itself (or "
                             "inside one of its frames): the results would be read as frames")
        groups.append((_folder_pairs(path, out), None) if path.is_dir() else _manifest_pairs(path))
    pairs = _told_apart(groups)
    seen: dict[str, Pair] = {}
    for pair in pairs:
        # (casefolded: Scene and scene are one folder on macOS and Windows, and where the
        # results are copied to; the second pair's result had replaced the first's)
        folded = _folded(pair.name)
        first = seen.get(folded)
        if first is not None:
            named = (f"both named {pair.name!r}" if first.name == pair.name else
                     f"named {first.name!r} and {pair.name!r}, one folder on macOS and Windows (which tell apart "
                     "neither case nor an accent's two forms)")
            raise ValueError(f"two pairs are {named} ({first.t1} → {first.t2} and {pair.t1} → {pair.t2}); name "
                             "them in a manifest's third column")
        seen[folded] = pair
    return pairs


def _told_apart(groups: list[tuple[list[Pair], list[bool] | None]]) -> list[Pair]:
    """The pairs of every source, in order, where names that a pair was given by default
    (t1's stem) collide, told apart by the folders that hold their frames: ``A-lf1`` and
    ``B-lf1`` for ``A/lf1.npz`` and ``B/lf1.npz`` (two folders of ``lfsf synth``, two
    sequences numbered alike: the batch had been refused), as many folders as it takes
    (``A-frames-f000`` and ``B-frames-f000`` for two ``lfsf synth --frames`` outputs). A
    folder of frames (``defaulted`` None) is renamed as a whole, its pairs' ``previous``
    with them; a manifest's pairs one by one, only those whose name ``defaulted`` (no
    third column). Names given in a manifest stay; where names still collide, the caller
    says so."""
    counts: dict[str, int] = {}
    for pairs, _ in groups:
        for pair in pairs:
            counts[_folded(pair.name)] = counts.get(_folded(pair.name), 0) + 1
    renamed = [[default and counts[_folded(pair.name)] > 1 for pair, default in
                zip(pairs, [True] * len(pairs) if defaulted is None else defaulted)] for pairs, defaulted in groups]
    for g, (pairs, defaulted) in enumerate(groups):
        if defaulted is None and any(renamed[g]):
            renamed[g] = [True] * len(pairs)

    def folders(pair: Pair) -> list[str]:
        # (the path as written, '..' taken out; a hidden folder's dot left out of the name)
        return [part.lstrip(".") for part in Path(os.path.normpath(pair.t1.parent)).parts[1:]][::-1]

    def prefixed(name: str | None, pair: Pair, depth: int) -> str | None:
        parts = [part for part in folders(pair)[:depth] if part][::-1]
        return None if name is None else "-".join([*parts, name])

    deepest = max((len(folders(pair)) for pairs, _ in groups for pair in pairs), default=0)
    for depth in range(1, deepest + 1):
        told = [dataclasses.replace(pair, name=prefixed(pair.name, pair, depth),
                                    previous=prefixed(pair.previous, pair, depth)) if rename else pair
                for (pairs, _), flags in zip(groups, renamed) for pair, rename in zip(pairs, flags)]
        if len({_folded(pair.name) for pair in told}) == len(told):
            return told
    return [pair for pairs, _ in groups for pair in pairs]


def _folded(name: str) -> str:
    """A pair's name as macOS and Windows compare folder names, about: composed (macOS
    takes é and e + ◌́ for one name) and case-folded (it over-refuses Straße against STRASSE,
    two folders on NTFS)."""
    import unicodedata

    return unicodedata.normalize("NFC", name).casefold()


#: The longest manifest read: some 300 000 pairs.
MAX_MANIFEST_BYTES = 64 << 20


def _manifest_pairs(path: Path) -> tuple[list[Pair], list[bool]]:
    """A manifest's pairs, and for each whether its name is t1's stem by default."""
    try:
        # (-sig: Excel's "CSV UTF-8" starts with a BOM; a named pipe is read, /dev/zero is not for ever)
        text = read_capped(path, MAX_MANIFEST_BYTES, "a manifest").decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text CSV manifest") from None
    if "\0" in text:  # (before the csv module: Python 3.10's refuses the line with an error of its own)
        line = text.count("\n", 0, text.index("\0")) + 1
        raise ValueError(f"{path}: line {line} holds a NUL byte, which no path or name can")
    # comment lines (# …, unquoted: a quoted "#name.npz" is a path) blanked, keeping the
    # lines' numbers; (line number, row) of the rest but blank lines, the line where a row
    # ends (a quoted cell may span lines)
    text = "\n".join("" if line.lstrip().startswith("#") else line for line in text.split("\n"))
    reader = csv.reader(_io.StringIO(text))
    rows = []
    try:
        rows.extend((reader.line_num, row) for row in reader if row and any(c.strip() for c in row))
    except csv.Error as exc:  # (a stray quote runs a cell on past the csv module's limit: 128 KiB)
        raise ValueError(f"{path}: line {reader.line_num} does not read as CSV ({exc}); a stray \" "
                         "quote?") from None
    if rows and [c.strip().lower() for c in rows[0][1][:2]] == ["t1", "t2"]:
        rows = rows[1:]
    if not rows:
        raise ValueError(f"{path}: the manifest names no pairs (expected lines 't1,t2[,name]')")
    pairs, defaulted = [], []
    for line, row in rows:
        cells = [c.strip() for c in row]
        if len(cells) not in (2, 3) or not cells[0] or not cells[1]:
            raise ValueError(f"{path}: line {line} ({','.join(row)!r}) is not 't1,t2[,name]' (a header, if "
                             "any, is 't1,t2[,name]' too)")
        t1, t2 = ((path.parent / c) for c in cells[:2])
        name = cells[2] if len(cells) == 3 and cells[2] else _stem(t1)
        if not name or name.startswith(".") or "/" in name or "\\" in name:
            raise ValueError(f"{path}: line {line} names the pair {name!r}, which cannot be a folder name")
        pairs.append(Pair(name, t1, t2))
        defaulted.append(len(cells) < 3 or not cells[2])
    return pairs, defaulted


#: Names that Windows keeps for devices, with or without an extension (``NUL.txt``).
_WINDOWS_DEVICES = {"con", "prn", "aux", "nul", "conin$", "conout$",
                    *(f"{kind}{n}" for kind in ("com", "lpt") for n in (*"0123456789", "¹", "²", "³"))}


def _not_a_windows_folder(name: str, windows: bool = os.name == "nt") -> bool:
    """On Windows (``windows``), whether ``name`` cannot be a folder's there: one of
    ``<>:"|?*`` or a control character in it, a device's name (CON, NUL.x, COM1, …), or a
    dot or space at its end (a pair would fail only after its estimate)."""
    return windows and (any(c in '<>:"|?*' or ord(c) < 32 for c in name) or name.endswith((".", " "))
                        or name.split(".")[0].rstrip(" ").lower() in _WINDOWS_DEVICES)


def _within(path: Path, folder: Path) -> bool:
    """``path`` is ``folder`` or lies inside it (absolute paths, compared as resolved)."""
    path, folder = resolved(path), resolved(folder)
    return path == folder or folder in path.parents


def frame_order(paths) -> list[Path]:
    """A folder's frames in order: by name, but where every name is one counter between
    the same prefix and suffix (``f1.npz``, ``f2.npz``, ``f10.npz``: a camera's unpadded
    counter), by the counter's value (plain sorting had paired f1 with f10 and f10 with
    f2). Not where the prefix ends in a point: ``t0.5``, ``t0.25`` are fractions, which
    sort by name."""
    paths = sorted(paths, key=lambda p: p.name)
    # (a frame's name less .npz: a sub-folder f9 and a file f10.npz count alike)
    parts = [re.fullmatch(r"(.*?)(\d+)(\D*)", p.stem if p.suffix.lower() in FRAME_SUFFIXES else p.name)
             for p in paths]
    if (all(parts) and len({(m.group(1), m.group(3)) for m in parts}) == 1
            and not parts[0].group(1).endswith(".")):
        order = {id(p): int(m.group(2)) for p, m in zip(paths, parts)}
        return sorted(paths, key=lambda p: order[id(p)])
    return paths


def _folder_pairs(folder: Path, out: Path | None = None) -> list[Pair]:
    frames = frame_order(p for p in folder.iterdir()
                         if not p.name.startswith(".") and (p.is_dir() or p.suffix.lower() in FRAME_SUFFIXES)
                         and p.name.lower() not in GROUND_TRUTH_NAMES
                         and not (out is not None and _within(out, p)))
    if len(frames) < 2:
        from lfsf.io import read_lightfield

        alone = ""
        with contextlib.suppress(Exception):  # (a folder of views is one light field, not frames)
            lf = read_lightfield(folder)
            alone = f"; it is itself one light field ({lf.grid[0]}×{lf.grid[1]} views), not a folder of frames"
        if frames == [folder / "frames"] and (folder / "gt").is_dir():
            alone = f"; lfsf synth --frames wrote its frames into {folder / 'frames'}: give that folder"
        raise ValueError(f"{folder}: a folder of frames needs at least two light fields (sub-folders of views "
                         f"or .npz files), found {len(frames)}{alone}")
    pairs, previous = [], None
    for a, b in zip(frames[:-1], frames[1:]):
        pairs.append(Pair(_stem(a), a, b, previous, sequence=True))
        previous = pairs[-1].name
    return pairs


def _stem(path: Path) -> str:
    return path.name[: -len(path.suffix)] if path.suffix.lower() in FRAME_SUFFIXES else path.name


# --- one task -------------------------------------------------------------------------------

def is_complete(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` holds a complete result: every file there and whole
    (:func:`_whole`: a truncated ``flow.flo`` or an emptied picture had counted as
    complete, and a re-run skipped it)."""
    folder = Path(folder)
    return all((folder / name).is_file() and _whole(folder / name) for name in RESULT_FILES)


def _whole(path: Path) -> bool:
    """Whether a result file holds what its header promises: a PFM or FLO that
    :func:`lfsf.io.read_pfm` or :func:`lfsf.io.read_flo` reads (the maps are small beside
    the ``sceneflow.npz`` a re-run reads anyway), anything else at least one byte."""
    from lfsf import io

    try:
        if path.suffix == ".flo":
            io.read_flo(path)
        elif path.suffix == ".pfm":
            io.read_pfm(path)
        else:
            return path.stat().st_size > 0
    except (OSError, ValueError):
        return False
    return True


#: Which earlier results a re-run estimates again and replaces.
REPLACED_WHICH = "of other settings or inputs, incomplete, or unreadable"
#: An :class:`Outcome`'s reason where a pair was estimated again over an earlier result.
REPLACED = f"replaced an earlier result ({REPLACED_WHICH})"


def input_record(pair: Pair, warm_start: bool, out: str | os.PathLike | None = None) -> dict:
    """What a result records of how it came about, besides the settings, and a re-run
    compares: each light field's path (symbolic links resolved) and, for its file or each
    file of its folder but hidden ones (``.DS_Store``, editors' swap files), the size and
    the modification time (ns), as ``make`` tells a changed input; and whether the pair
    was to start from the previous one's result. Light fields moved, or copied without
    their times, are estimated again. With a warm start and ``out`` (the batch's output
    folder), also the size and time of the previous pair's ``sceneflow.npz`` that it
    starts from (None: none there): a pair whose predecessor was estimated again since
    is estimated again too, from the new start."""
    def stamp(path: Path) -> list:
        status = path.stat()
        return [status.st_size, status.st_mtime_ns]

    def files(path: Path) -> list:
        entries = sorted(path.iterdir()) if path.is_dir() else [path]
        return [[e.name, *stamp(e)] for e in entries if e.is_file() and not (path.is_dir() and e.name.startswith("."))]

    warm = bool(warm_start and pair.previous is not None)
    record = {"t1": str(resolved(pair.t1)), "t2": str(resolved(pair.t2)), "t1_files": files(pair.t1),
              "t2_files": files(pair.t2), "warm_start": warm}
    if warm and out is not None:
        start = Path(out) / pair.previous / "sceneflow.npz"
        record["previous"] = stamp(start) if start.is_file() else None
    return record


def _estimated_with(folder: Path, params, inputs: dict) -> bool:
    """Whether the complete result in ``folder`` was estimated with the settings
    ``params`` (None: the `paper` preset) from the inputs ``inputs``
    (:func:`input_record`): its sceneflow.npz reads, maps and all, and records these.
    Anything else (other settings, light fields changed, renamed or swapped since, a
    file cut short or not lfsf's) is no result of this run, and a re-run estimates the
    pair again."""
    import json

    from lfsf.params import Params

    try:  # (the file read once: its maps, and the record of its settings and inputs)
        with np.load(folder / "sceneflow.npz") as z:
            for key in ("disp1", "disp2", "u", "v"):
                z[key]
            record = json.loads(str(z["params"]))
        recorded = Params.recorded(record["params"])
    except Exception:  # noqa: BLE001 - whatever fails to read is no result of this run
        return False
    # (through JSON, as the record was: lists for tuples)
    return (recorded == (Params.preset("paper") if params is None else params)
            and record.get("inputs") == json.loads(json.dumps(inputs)))


def _refuse_foreign(folder: Path) -> None:
    """Raise ValueError unless the existing result folder ``folder`` holds nothing but
    (some of) a result's files, and the temporary folders of an ``lfsf run`` into it that
    was killed (:func:`lfsf._files.dead_set`), so that an incomplete result may be
    replaced without losing anything else. A live run's, or another machine's, is not
    ours to remove. The message names what else is there (the first five entries)."""
    if not folder.is_dir():
        raise ValueError(f"{folder}: the result's place holds a file, not a folder; not replaced")
    names = set(RESULT_FILES) | {"overview.png"}
    foreign = sorted(p.name + (" (a running lfsf's temporary files)" if p.name.startswith(SET_PREFIX) else "")
                     for p in folder.iterdir() if not (p.is_file() and p.name in names or dead_set(p)))
    if foreign:
        more = f" and {len(foreign) - 5} more" if len(foreign) > 5 else ""
        raise ValueError(f"{folder}: holds what lfsf does not write ({', '.join(foreign[:5])}{more}); not "
                         "replaced: move it away, or choose another --out")


#: The longest pair name, in bytes: its temporary folder adds 37 (".", ".part-", 12 hex
#: digits of the machine, "-", a process id, "-" and 8 hex digits) and file systems take 255.
MAX_PAIR_NAME = 200


def check_outputs(pairs: Sequence[Pair], out: str | os.PathLike) -> None:
    """Before any work: no pair's result folder ``out/NAME`` may be, or hold, a light
    field that a pair reads (it would be replaced), and none may be a file.

    Raises
    ------
    ValueError
        Naming the result folder and the source it would replace.
    """
    out = Path(out).absolute()
    # each source's resolved path and every folder above it, to the source (the first
    # such): a result folder that is one of them would replace it (a pair against every
    # source had taken 13 s for 400 pairs, minutes for thousands)
    held: dict[Path, Path] = {}
    for source in (Path(p).absolute() for pair in pairs for p in (pair.t1, pair.t2)):
        at = resolved(source)
        for above in (at, *at.parents):
            held.setdefault(above, source)
    for pair in pairs:
        # its folder and the temporary ".NAME.part-HOST-PID-XXXXXXXX" beside it must be names
        # the file system takes (255 bytes), and it must not be the list of failures
        if len(os.fsencode(pair.name)) > MAX_PAIR_NAME or "\0" in pair.name:
            raise ValueError(f"pair {pair.name[:40]!r}…: a pair's name must be a folder name of at most "
                             f"{MAX_PAIR_NAME} bytes; name it in a manifest's third column")
        if any(ord(c) < 32 or 127 <= ord(c) < 160 for c in pair.name):   # (an escape had been printed raw)
            raise ValueError(f"pair {pair.name!r}: a control character (a line break, a tab, an escape) in a pair's "
                             "name; name it in a manifest's third column")
        if _not_a_windows_folder(pair.name):  # (the pair would fail after its estimate)
            raise ValueError(f"pair {pair.name!r}: Windows takes no folder of that name (one of <>:\"|?* or a "
                             "control character in it, a device's name as CON or NUL, or a dot or space at its "
                             "end); name it in a manifest's third column")
        if _folded(pair.name) == "failed.csv":   # (Failed.CSV too, on macOS and Windows)
            raise ValueError(f"{out / pair.name}: a pair may not be named failed.csv, the list of failed pairs")
        final = out / pair.name
        source = held.get(resolved(final))
        if source is not None:
            raise ValueError(f"{final}: the results of pair {pair.name!r} would replace the light field "
                             f"{source}; choose another --out (or name the pair in the manifest)")
        if final.is_symlink():  # (replaced whole after the estimate, which rmtree refuses on a link)
            raise ValueError(f"{final}: the results of pair {pair.name!r} go into a folder there, but it is a "
                             f"symbolic link (to {os.readlink(final)}); remove it, or choose another --out")
        if final.exists() and not final.is_dir():
            raise ValueError(f"{final}: the results of pair {pair.name!r} go into a folder there, but it is a file")


def check_warm_start(pairs: Sequence[Pair], warm_start: bool) -> None:
    """``warm_start`` needs a sequence: the frames of a folder, whose pairs follow one
    another (two frames make one pair, which starts cold). A manifest's pairs stand alone
    (none starts from another's result).

    Raises
    ------
    ValueError
        ``warm_start`` where no pair follows another.
    """
    if warm_start and not any(pair.sequence or pair.previous is not None for pair in pairs):
        raise ValueError("--warm-start chains the pairs of a folder of frames, each starting from the one "
                         "before; these pairs come from manifests, whose pairs stand alone: give the folder "
                         "of frames, or leave --warm-start out")


def run_pair(pair: Pair, out: str | os.PathLike, params, device: str | None = None,
             warm_start: bool = False, _after=None) -> Outcome:
    """Estimate one pair and write its results to ``out/pair.name`` (skipped when complete).

    Errors in the pair (unreadable input, mismatched light fields, …) come back as a
    ``failed`` :class:`Outcome` with the reason; they are not raised, so that a Dask retry
    is spent only on a worker that died. ``_after`` is not used (a dependency a caller may
    give Dask; lfsf submits a warm-started pair only once the one before it has ended).
    """
    from lfsf.estimate import WARNINGS_TO_PROGRESS, Note, Warned, estimate_scene_flow, predict_next
    from lfsf.io import check_pair, read_lightfield

    out = Path(out)
    final = out / pair.name
    t0 = time.perf_counter()
    tmp = None
    try:  # all of it: a name too long for the file system fails here, in is_complete
        replaced = ""
        # (taken before reading them: a file changed while the pair runs is taken again)
        inputs = input_record(pair, warm_start, out) if pair.t1.exists() and pair.t2.exists() else None
        if is_complete(final) and inputs is not None and _estimated_with(final, params, inputs):
            return Outcome(pair.name, "skipped")
        if final.exists():
            replaced = REPLACED
        # (a gone process's: another batch's into the same folder, alive, is its own; removing
        # it had failed that batch's pair with "No such file or directory", a helper's two batches)
        _remove_stale(out, pair.name)
        tmp = _temporary(out, pair.name)
        tmp.mkdir(parents=True)
        if final.exists():  # (before the work, which would be lost)
            _refuse_foreign(final)
        lf1 = read_lightfield(pair.t1)
        lf2 = read_lightfield(pair.t2)
        check_pair(lf1, lf2)
        init = None
        if warm_start and pair.previous is not None:
            init = _previous_estimate(out / pair.previous, lf1.centre.shape[:2])
            init = None if init is None else predict_next(init)
        notes, warned = [], []

        def progress(line: str) -> None:
            if isinstance(line, Warned):
                warned.append(str(line))
            elif isinstance(line, Note):
                notes.append(str(line))

        # the estimator's warnings come to progress, this thread's alone (a worker runs pairs
        # on threads, which share the warnings module's filters; and its stderr is no one's)
        token = WARNINGS_TO_PROGRESS.set(True)
        # the centre views copied, the light fields handed over (the estimate lets them go
        # once sampled, as lfsf run)
        centre1, centre2 = np.array(lf1.centre), np.array(lf2.centre)
        given = [lf1, lf2]
        del lf1, lf2
        try:
            sf = estimate_scene_flow(given.pop(0), given.pop(0), params, device=_worker_device(device), init=init,
                                     progress=progress)
        finally:
            WARNINGS_TO_PROGRESS.reset(token)
        sf.save(tmp, centre1, centre2, inputs=inputs)   # (with overview.png, as lfsf run)
        if final.exists():  # an earlier result, complete or not, or one left by hand
            _refuse_foreign(final)  # (what was put there while the pair ran)
            # moved aside, not removed in place: a reader had seen the folder with part of its
            # files (a helper's SceneFlow.load in a loop, 526 times); removed once the new one
            # is in (a process killed meanwhile leaves it hidden, as a gone process's)
            earlier = _temporary(out, pair.name)
            replace(final, earlier)
            try:
                replace(tmp, final)
            except BaseException as exc:
                try:
                    replace(earlier, final)
                except OSError as back:  # (another process's result there meanwhile: both said)
                    raise OSError(f"{final}: the new result could not be put in ({exc}), nor the earlier one "
                                  f"back ({back}); the earlier one is in {earlier}") from exc
                raise
            shutil.rmtree(earlier, ignore_errors=True)
        else:
            replace(tmp, final)
        return Outcome(pair.name, "done", time.perf_counter() - t0, replaced, warm=init is not None,
                       notes=tuple(notes), warned=tuple(warned))
    except Exception as exc:  # noqa: BLE001 - every failure of a pair is reported, the batch goes on
        reason = _reason(exc)
        return Outcome(pair.name, "failed", time.perf_counter() - t0, reason)
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)     # (not there, or its name unusable: nothing to do)


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno in _FULL:  # (its file is the pair's temporary folder's, removed)
        return f"no space left on the device ({exc.strerror}); nothing of the pair was kept"
    if isinstance(exc, BAD_INPUT_ERRORS):
        return str(exc)
    if isinstance(exc, AssertionError) and _raised_in(exc, "distributed", "_start_unlocked"):
        # distributed's LoopRunner asserts that its event loop's thread started within 10 s
        return ("Dask's event loop did not start in time; a machine this busy or short of memory "
                "may do that: try again")
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ else None
    at = f" (at {Path(where.filename).name}:{where.lineno})" if where else ""
    return f"{type(exc).__name__}: {exc}{at}"


def _raised_in(exc: BaseException, package: str, function: str) -> bool:
    """Whether ``exc`` was raised in ``function`` of the installed ``package`` (its last
    frame)."""
    frames = traceback.extract_tb(exc.__traceback__) if exc.__traceback__ else []
    return bool(frames) and frames[-1].name == function and package in Path(frames[-1].filename).parts


def _temporary(out: Path, name: str) -> Path:
    """A new name for a temporary folder of pair ``name`` in ``out``, of this machine
    (:func:`lfsf._files._host`) and process: ``.NAME.part-HOST-PID-XXXXXXXX``."""
    return out / f".{name}.part-{_host()}-{os.getpid()}-{uuid.uuid4().hex[:8]}"


#: A pair's temporary folder older than this is a gone process's whatever its name says:
#: another machine's (a worker killed there, its pair run again here), or any off POSIX.
STALE_PART_AGE = 24 * 3600.0


def _remove_stale(out: Path, name: str) -> None:
    """The temporary folders of pair ``name`` whose process is gone (a killed worker's, an
    interrupted batch's), or older than :data:`STALE_PART_AGE`; another live process's,
    such as another batch's into the same folder, stay."""
    if out.is_dir():
        now = time.time()
        for stale in out.glob(f".{glob.escape(name)}.part-*"):
            with contextlib.suppress(OSError):
                if not _process_alive(stale.name) or now - stale.stat().st_mtime > STALE_PART_AGE:
                    shutil.rmtree(stale, ignore_errors=True)


def _process_alive(temporary: str) -> bool:
    """Whether the process that made the temporary folder ``.NAME.part-HOST-PID-XXXXXXXX``
    may still be writing it: True unless it is a process of this machine that is gone.
    Another machine's (a cluster's shared file system), this process's own, a name of
    another form and anything off POSIX read as alive. (The ``.NAME.part-PID-XXXXXXXX``
    of lfsf before the fifty-eighth session had no machine: judged by the process alone.)"""
    match = re.search(r"\.part-(?:([0-9a-f]{12})-)?(\d+)-[0-9a-f]{8}$", temporary)
    return match is None or not gone(int(match.group(2)), match.group(1))


def _previous_estimate(folder: Path, shape) -> dict | None:
    """The previous pair's estimate, if it is complete and of the same size."""
    from lfsf.evaluate import load_estimate

    if not is_complete(folder):
        return None
    maps = load_estimate(folder)
    return maps if maps["disp1"].shape == tuple(shape) else None


def _worker_device(device: str | None) -> str:
    """The device for this task: the one asked for, else, on a Dask worker of a machine
    with several GPUs, one GPU per worker (by the worker's number), else the default."""
    from lfsf.device import available_devices, resolve_device

    if device:
        return resolve_device(device)
    gpus = [d for d in available_devices() if d.startswith("cuda")]
    if len(gpus) > 1:
        with contextlib.suppress(Exception):
            from distributed import get_worker

            number = get_worker().name
            if isinstance(number, int):
                return gpus[number % len(gpus)]
    return resolve_device(None)


# --- the batch --------------------------------------------------------------------------------

def have_dask() -> bool:
    """Whether Dask's ``distributed`` imports (a batch without it runs in this process)."""
    return _dask_problem() is None


def _dask_problem() -> str | None:
    """None where Dask's ``distributed`` imports; else why not: "not installed", or the
    error of one that is installed and fails to import (a dependency of its own broken, or
    of another version), which had read as "not installed"."""
    try:
        import distributed  # noqa: F401
    except ImportError as exc:
        missing = isinstance(exc, ModuleNotFoundError) and exc.name in ("distributed", "dask")
        return "not installed" if missing else f"installed but does not import ({exc})"
    return None


def check_dask(workers: int, scheduler: str | None) -> None:
    """Raise ValueError, saying how to install it, when the execution asked for needs
    Dask and Dask is not installed (one worker runs in this process without it), or when
    ``workers`` is not a whole number of at least 1."""
    if whole(workers) is None or workers < 1:
        # (run_batch's own check: -1 had waited forever on a cluster of no workers, 0 divided by zero)
        raise ValueError(f"workers must be a whole number of at least 1, got {workers!r}")
    from lfsf.device import usable_cpus

    cores = usable_cpus()
    if not scheduler and workers > cores:
        # each worker runs the estimator on threads of its own: more processes than cores
        # only divide them, and multiply the memory (hundreds of MB each)
        raise ValueError(f"--workers {workers}: this process may use {cores} CPU{'s' if cores != 1 else ''} (the "
                         f"machine's, or its share of them); give at most {cores}")
    problem = _dask_problem() if workers > 1 or scheduler else None
    if problem is not None:
        # (--workers and --scheduler together are refused by the command line)
        asked, instead = (("--scheduler", "leave out --scheduler") if scheduler else
                          (f"--workers {workers}", "run with --workers 1"))
        raise (ValueError if problem == "not installed" else DependencyError)(
            f"{asked} needs Dask, which is {problem}: {INSTALL_HINT}; or {instead} to run the pairs in this process")
    if not scheduler and have_dask():
        try:
            os.getcwd()
        except OSError:  # (the local cluster's processes start there: 186 lines of their tracebacks)
            raise ValueError("the current folder no longer exists, and the local Dask cluster's processes "
                             "start in it: change to a folder that exists") from None


def run_batch(
    pairs: Sequence[Pair],
    out: str | os.PathLike,
    params,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    device: str | None = None,
    warm_start: bool = False,
    retries: int = 2,
    progress: Callable[[Outcome, int, int], None] | None = None,
) -> Summary:
    """Run every pair and write ``out/failed.csv`` (name, t1, t2, reason) if any failed.

    Parameters
    ----------
    pairs : from :func:`pairs_from_sources`
    out : the output folder
    params : :class:`lfsf.Params` for every pair
    workers : processes of the local Dask cluster; 1 without Dask runs in this process
    scheduler : address of a running Dask scheduler (``tcp://host:8786``) instead
    device : for every task (default: each worker's own, one GPU per worker)
    warm_start : start each pair of a sequence from the previous one's result
    retries : Dask's extra attempts of a task that raised (one whose worker died is
        tried again as the scheduler's ``allowed-failures`` say, 3 by default)
    progress : called after each pair with its outcome, the pairs finished and the total

    Returns
    -------
    Summary
    """
    out = Path(out).absolute()
    t0 = time.perf_counter()
    given = progress or (lambda outcome, finished, total: None)
    known: list[Outcome] = []  # (this run's outcomes so far: what an interrupted run leaves in failed.csv)

    def report(outcome: Outcome, finished: int, total: int) -> None:
        known.append(outcome)
        given(outcome, finished, total)

    report.interrupted = getattr(given, "interrupted", None)  # type: ignore[attr-defined]
    check_outputs(pairs, out)
    check_warm_start(pairs, warm_start)
    check_dask(workers, scheduler)
    workers = whole(workers)  # (2.0 as 2)
    summaries: list[Summary] = []

    def finish(outcomes) -> None:
        summaries.append(Summary(outcomes, time.perf_counter() - t0))
        _write_failed(out, pairs, summaries[-1])

    try:
        if scheduler is None and workers == 1 and not have_dask():
            out.mkdir(parents=True, exist_ok=True)
            finish(_run_here(pairs, out, params, device, warm_start, report))
        else:
            # (failed.csv written before the cluster closes: an interrupt while it closes, some
            # seconds, had lost it)
            _run_dask(pairs, out, params, workers, scheduler, device, warm_start, retries, report, finish)
    except KeyboardInterrupt:  # (Ctrl-C, SIGTERM: lfsf's Terminated is one)
        if not summaries and known and out.is_dir():
            _update_failed(out, pairs, known)
        raise
    return summaries[-1]


def _update_failed(out: Path, pairs: Sequence[Pair], outcomes: list) -> None:
    """``out/failed.csv`` after an interrupted run: an earlier run's rows of the pairs this
    one has ended (done, skipped or failed again) dropped, this one's failures added;
    the pairs it did not reach keep their rows. (It had been left as it was: pairs done
    since were still listed as failed, and this run's failures were not.)"""
    path = out / "failed.csv"
    ended = {o.name for o in outcomes}
    kept = []
    with contextlib.suppress(OSError, UnicodeDecodeError, csv.Error):
        with open(path, newline="", encoding="utf-8", errors="surrogateescape") as f:
            kept = [row for row in csv.DictReader(f) if row.get("name") not in ended]
    earlier = [(r.get("name", ""), r.get("t1", ""), r.get("t2", ""), r.get("reason", "")) for r in kept]
    _write_failed_rows(path, pairs, [o for o in outcomes if o.status == "failed"], earlier)


def _run_here(pairs, out, params, device, warm_start, report) -> list[Outcome]:
    outcomes = []
    for pair in pairs:
        outcomes.append(run_pair(pair, out, params, device, warm_start))
        report(outcomes[-1], len(outcomes), len(pairs))
    return outcomes


#: How long a batch waits for a running scheduler to have a worker before it gives up.
WORKER_WAIT = "30s"


def check_scheduler_address(address: str) -> None:
    """A ValueError naming ``--scheduler`` unless ``address`` is ``tcp://HOST:PORT`` (or
    ``HOST:PORT``) with a port in 1…65535: the other protocols need settings (TLS
    certificates, UCX) that a batch does not take, and a malformed address was a
    traceback, a vague message or a silent local cluster ('')."""
    match = re.fullmatch(r"(?:tcp://)?([^/:\s]+|\[[0-9a-fA-F:.]+\]):(\d{1,5})", address)
    if match is None or not 1 <= int(match.group(2)) <= 65535:
        raise ValueError(f"--scheduler {address!r}: expected a running Dask scheduler's address, "
                         "tcp://HOST:PORT with a port in 1…65535")


def _run_dask(pairs, out, params, workers, scheduler, device, warm_start, retries, report, finish) -> None:
    try:
        _run_on_cluster(pairs, out, params, workers, scheduler, device, warm_start, retries, report, finish)
    finally:
        if not scheduler and out.is_dir():
            # the local cluster is closed by now: what its workers were writing when an
            # interrupt (Ctrl-C, SIGTERM) ended them is no one's any more (a remote
            # scheduler's workers go on with theirs, and their next attempt clears them;
            # another batch's into the same folder, alive, keeps its own)
            for pair in pairs:
                _remove_stale(out, pair.name)


def _close_what_failed() -> None:
    """Collect the garbage now, after a Dask Client or cluster failed in its constructor
    (outside the ``except``, so that the error, its frames and the half-made object are
    garbage): that object closes itself in its ``__del__``, which takes the lock of
    distributed's event-loop runner. Collected later, within another Client's or
    cluster's start, which holds that lock, it deadlocked (this project's test run hung
    in a LocalCluster's start, a failed Client of an earlier test closing inside it)."""
    import gc

    gc.collect()


def _run_on_cluster(pairs, out, params, workers, scheduler, device, warm_start, retries, report, finish) -> None:
    """The pairs on a Dask cluster (a local one, or ``scheduler``'s); ``finish`` gets the
    outcomes once all are in, before the cluster closes."""
    import asyncio
    import logging

    import dask
    from distributed import Client, LocalCluster, as_completed

    with contextlib.ExitStack() as stack:
        if scheduler:
            check_scheduler_address(scheduler)
            failure = None
            try:
                client = stack.enter_context(Client(scheduler, timeout="10s"))
            except MemoryError:
                # a server that is not Dask's answered: its first bytes ("HTTP/1.1") read as
                # a message length of exabytes, reported as out of memory
                failure = ValueError(f"cannot reach the Dask scheduler at {scheduler}: what answers there is not a "
                                     "Dask scheduler (a dashboard's port, 8787, or another server's?)")
            except (OSError, ValueError, TypeError) as exc:
                failure = ValueError(f"cannot reach the Dask scheduler at {scheduler}: {exc}")
            except AssertionError as exc:  # (the client's own event loop did not start)
                failure = MachineError(f"cannot reach the Dask scheduler at {scheduler}: {_reason(exc)}")
            if failure is not None:
                _close_what_failed()
                raise failure
            try:    # a scheduler without workers would take the tasks and wait for ever
                client.wait_for_workers(1, timeout=WORKER_WAIT)
            except (TimeoutError, asyncio.TimeoutError, OSError):  # (Python 3.10: asyncio's is another class)
                raise ValueError(f"the Dask scheduler at {scheduler} has had no worker for {WORKER_WAIT}; "
                                 "start one (dask worker ADDRESS)") from None
        else:
            # one thread per worker: the estimator runs its own CPU threads
            from lfsf.device import usable_cpus

            threads = max(1, usable_cpus() // workers)
            # (the workers ignore Ctrl-C once started: lfsf._dask_worker)
            with warnings.catch_warnings():
                # the scheduler's HTTP server (no dashboard here) takes another port where
                # 8787 is taken, as by another cluster, and said so as a warning of the batch
                warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")
                _start_resource_tracker_deaf_to_hangups()
                # one pair a worker at a time (Dask holds 1.1 tasks a thread by default: a second pair
                # queued on a worker that kept dying had failed with the pair that killed it)
                stack.enter_context(dask.config.set({"distributed.scheduler.worker-saturation": 1.0}))
                failure = None
                try:
                    cluster = stack.enter_context(LocalCluster(
                        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                        silence_logs=logging.ERROR, env={"LFSF_THREADS": str(threads)},
                        preload=["lfsf._dask_worker"]))
                except (OSError, RuntimeError, TimeoutError, AssertionError) as exc:  # (its traceback says no more)
                    failure = MachineError(f"the local Dask cluster did not start ({_reason(exc)})")
                if failure is not None:
                    _close_what_failed()
                    raise failure
            client = stack.enter_context(Client(cluster))
        out.mkdir(parents=True, exist_ok=True)  # only once there is a cluster to write into it
        futures = {}

        def submit(index: int):
            future = client.submit(run_pair, pairs[index], str(out), params, device, warm_start, None,
                                   key=f"lfsf-{pairs[index].name}-{uuid.uuid4().hex[:8]}", retries=retries,
                                   pure=False)
            futures[future] = index
            return future

        # With --warm-start a pair goes to the cluster once the pair before it has ended,
        # done or failed (it then starts cold). Given as a Dask dependency, a pair whose
        # worker died failed every later pair of its sequence with its own reason.
        names = {pair.name for pair in pairs}
        after: dict[str, list[int]] = {}
        first = []
        for index, pair in enumerate(pairs):
            if warm_start and pair.previous in names:
                after.setdefault(pair.previous, []).append(index)
            else:
                first.append(index)
        queue = as_completed([submit(index) for index in first])
        outcomes: list[Outcome | None] = [None] * len(pairs)
        finished = 0

        def ended(future) -> None:
            nonlocal finished
            index = futures[future]
            try:
                outcome = future.result()
            except Exception as exc:  # noqa: BLE001 - a task that died on every attempt
                outcome = Outcome(pairs[index].name, "failed", reason=_dask_reason(exc))
                _remove_stale(out, pairs[index].name)   # the last dead attempt's folder: no retry will
            outcomes[index] = outcome
            finished += 1
            report(outcome, finished, len(pairs))

        try:
            for future in queue:
                ended(future)
                for successor in after.pop(pairs[futures[future]].name, []):
                    queue.add(submit(successor))
        except KeyboardInterrupt as exc:
            # (the wait for the pairs begun had been silent, and a second Ctrl-C abandoned them;
            # Ctrl-C alone: a SIGTERM or SIGHUP sent to the process group ends the workers too)
            if type(exc) is KeyboardInterrupt and not scheduler and finished < len(pairs):
                if callable(getattr(report, "interrupted", None)):
                    report.interrupted()
                # (a second Ctrl-C raises out of it: abandoned; the pairs ended meanwhile, or
                # before and not yet taken, are reported, and so reach failed.csv)
                for future in _finish_begun(client, list(futures)):
                    if outcomes[futures[future]] is None:
                        ended(future)
                # (and those that ended meanwhile by another way: between the workers' answer and
                # the check of the futures, or before, not yet taken from the queue)
                for future in [f for f in futures if f.status in ("finished", "error")
                               and outcomes[futures[f]] is None]:
                    ended(future)
            raise
        finish(outcomes)


def _executing(dask_worker) -> list:
    """The keys of the tasks a Dask worker runs now (``Client.run`` on every worker)."""
    return [task.key for task in dask_worker.state.executing]


def _finish_begun(client, futures: list):
    """After a Ctrl-C: cancel the pairs that no worker has begun and wait for those that
    the workers are running, which write their results, yielding each future as it ends
    (closing the local cluster had ended its workers within 4 s, and the pairs with them,
    though the batch said it was finishing them). A pair whose worker stops running it
    without its future ending (the worker died: Dask would run it again from its start,
    up to three times) is cancelled, not waited for again."""
    def running() -> dict:   # key: the worker running it (those that answer)
        found = client.run(_executing, on_error="ignore")
        return {key: worker for worker, keys in found.items() for key in keys}

    try:
        begun = running()
    except Exception:  # noqa: BLE001 - the cluster gone meanwhile: nothing to wait for that can be told
        begun = {}
    waiting = {f: begun[f.key] for f in futures if f.key in begun}   # (done ones too: yielded at once)
    client.cancel([f for f in futures if f not in waiting and not f.done()])
    gone: dict = {}   # a future's polls since its worker stopped running it
    while waiting:
        time.sleep(0.2)
        for future in [f for f in waiting if f.done()]:
            del waiting[future]
            yield future
        try:
            now = running()
        except Exception:  # noqa: BLE001 - as above
            now = {}
        for future, worker in list(waiting.items()):
            gone[future] = 0 if now.get(future.key) == worker else gone.get(future, 0) + 1
            if gone[future] >= 5 and not future.done():  # (1 s: not a result on its way to the client)
                client.cancel([future])
                del waiting[future]


def _start_resource_tracker_deaf_to_hangups() -> None:
    """Start multiprocessing's resource tracker (which the local cluster's processes share)
    with SIGHUP blocked, as it blocks SIGINT and SIGTERM itself: a hang-up sent to the
    process group (an ssh session dropped) had killed it, and the one started again printed
    a traceback for each semaphore it had not seen (six, into the log)."""
    import signal

    if not hasattr(signal, "SIGHUP") or not hasattr(signal, "pthread_sigmask"):
        return
    from multiprocessing import resource_tracker

    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGHUP})
    try:
        resource_tracker.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _dask_reason(exc: BaseException) -> str:
    if type(exc).__name__ == "KilledWorker":
        # (how many attempts the scheduler allows is its own setting, allowed-failures)
        return "its worker process died on every attempt the scheduler allowed"
    return f"{type(exc).__name__}: {exc}"


def _write_failed(out: Path, pairs: Sequence[Pair], summary: Summary) -> None:
    """``out/failed.csv`` lists this run's failures; it is removed when there are none."""
    _write_failed_rows(out / "failed.csv", pairs, summary.failed)


def _write_failed_rows(path: Path, pairs: Sequence[Pair], failed: list, earlier=()) -> None:
    """``failed.csv``: the rows ``earlier`` (name, t1, t2, reason), then a row for each
    failed outcome of ``pairs``; removed where there are none."""
    by_name = {p.name: p for p in pairs}
    rows = [*earlier, *((o.name, by_name[o.name].t1, by_name[o.name].t2, o.reason) for o in failed)]
    if not rows:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        return
    text = _io.StringIO()
    writer = csv.writer(text)
    writer.writerow(["name", "t1", "t2", "reason"])
    writer.writerows(rows)
    # surrogateescape: a path of bytes that are not UTF-8 is written back as those bytes
    write_bytes_atomic(path, text.getvalue().encode("utf-8", "surrogateescape"))


# --- progress ----------------------------------------------------------------------------

class ProgressBar:
    """One bar over the pairs with the time left, on a terminal; one line per pair in a
    log; nothing with ``quiet``. Failures are always reported, with their reason, and the
    estimator's warnings on a pair; its notes (an exposure matched or refused, …) but with
    ``quiet``."""

    def __init__(self, total: int, quiet: bool = False, stream=None, width: int = 30):
        self.stream = stream or sys.stderr
        self.live = self.stream.isatty() and not quiet
        self.quiet = quiet
        self.total = total
        self.width = width
        self.t0 = time.perf_counter()
        self.failed = 0
        self.stopping = False
        self.shown = 0   # (the length of the bar's line on the terminal: blanked before a line of text)
        self.noted: set = set()  # (each note once: the same for every pair of a sequence had repeated)

    def __call__(self, outcome: Outcome, finished: int, total: int) -> None:
        self.failed += outcome.status == "failed"
        elapsed = time.perf_counter() - self.t0
        left = elapsed / finished * (total - finished)
        drawn = self.live and not self.stopping   # (after a Ctrl-C, lines: the bar would run into the last one)
        if outcome.status == "failed":  # (counted in a log, as every other pair's line)
            count = f"[{finished}/{total}] " if not drawn and not self.quiet else ""
            self._line(f"{count}pair {outcome.name} failed: {outcome.reason}")
        elif not drawn and not self.quiet:
            self._line(f"[{finished}/{total}] {outcome.name}: {outcome.status}"
                       + (f" in {outcome.seconds:.1f} s" if outcome.status == "done" else "")
                       + ("" if self.stopping else f"; about {_duration(left)} left"))
        if not self.quiet:  # what the estimator decided about the pair's input, on a terminal too
            for note in outcome.notes:
                if note not in self.noted:
                    self.noted.add(note)
                    self._line(f"pair {outcome.name}: {note}")
        for said in outcome.warned:  # (with --quiet too, as lfsf run's warnings)
            self._line(f"pair {outcome.name}: warning: {said}")
        if drawn:
            filled = int(round(self.width * finished / total))
            bar = "#" * filled + "." * (self.width - filled)
            failed = f", {self.failed} failed" if self.failed else ""
            line = (f"[{bar}] {finished}/{total} pairs{failed}, {_duration(elapsed)} elapsed, "
                    f"about {_duration(left)} left ")
            self.stream.write("\r" + line)
            self.shown = len(line)
            if finished == total:
                self.stream.write("\n")
                self.shown = 0
            self.stream.flush()

    def interrupted(self) -> None:
        """Said at a Ctrl-C while a local cluster's pairs in progress are finished."""
        self.stopping = True
        if not self.quiet:
            self._line("interrupted: finishing the pairs in progress, which the next run skips (Ctrl-C again "
                       "abandons them)")

    def _line(self, text: str) -> None:
        if self.live and self.shown:  # (blanks, not the escape ESC[K, which a TERM=dumb terminal shows)
            self.stream.write("\r" + " " * self.shown + "\r")
            self.shown = 0
        self.stream.write(f"lfsf batch: {text}\n")
        self.stream.flush()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"
