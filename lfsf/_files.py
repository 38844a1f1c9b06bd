"""Writing results safely: every output goes to a temporary name beside its target and is
renamed into place only once complete, so an interrupted run never leaves a half-written
file behind."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import tempfile
from pathlib import Path
from typing import Iterator


#: At most this many characters of a target's stem go into its temporary name.
TEMP_STEM = 40


def output_folder(path: str | os.PathLike, create: bool = True, names=()) -> Path:
    """``path`` as a folder to write results into, made if missing (unless ``create`` is
    false: then only what exists of it is checked): checked before any work, so that a
    run does not end, after minutes, on an output it cannot write. ``names``: the files
    that will be written into it, none of which may be a folder there.

    Raises
    ------
    ValueError
        If ``path`` (or a folder above it) is a file, or the folder is not writable.
    """
    if not os.fspath(path):
        raise ValueError("an empty folder name (it would be the current folder; give '.' for that)")
    path = Path(path)
    _check_name_lengths(path, path.parts, NAME_MAX)  # (before any stat: one too long fails it)
    for part in (path, *path.parents):
        if part.exists() and not part.is_dir():
            raise ValueError(f"{path}: cannot write results there: {part} is a file, not a folder")
        if part.is_symlink() and not part.exists():
            raise ValueError(f"{path}: cannot write results there: {part} is a broken symbolic link "
                             f"(to {os.readlink(part)})")
    existing = next(part for part in (path, *path.parents) if part.exists())
    if existing != path:
        why = _unwritable(existing)
        if why:
            raise ValueError(f"{path}: cannot make the output folder: {existing} is not writable ({why})")
        # the names of the folders still to make, against the file system's own bound (stat
        # says "no such file" of a name too long beneath a missing folder: it had failed
        # only when made, after the work)
        try:
            longest = os.pathconf(existing, "PC_NAME_MAX")
        except (AttributeError, OSError, ValueError):  # (no pathconf on Windows)
            longest = NAME_MAX
        _check_name_lengths(path, path.relative_to(existing).parts, longest)
    if create:
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"{path}: cannot make the output folder ({exc.strerror or exc})") from None
    if path.exists():
        why = _unwritable(path)
        if why:
            raise ValueError(f"{path}: the output folder is not writable ({why})")
    _check_names(path, names)
    return path


#: The longest name (bytes) of a file or folder on the usual file systems (ext4, XFS,
#: APFS, NTFS in UTF-16 units); :func:`output_folder` asks the file system where it can.
NAME_MAX = 255


def _check_name_lengths(path: Path, parts, longest: int) -> None:
    for part in parts:
        if len(os.fsencode(part)) > longest:
            raise ValueError(f"{path}: cannot make the output folder: the name {part[:40]}… is "
                             f"{len(os.fsencode(part))} bytes long, more than the {longest} a name may have")


def _unwritable(folder: Path) -> str:
    """Why nothing can be written in ``folder`` ("" if it can): a file made there and
    removed at once. ``os.access`` answers yes to root for any folder of a read-only
    file system (/sys, a read-only mount), where the run then failed after its work,
    naming its temporary file."""
    if not os.access(folder, os.W_OK | os.X_OK):
        return "permission denied"
    with interrupts_held():  # (Ctrl-C between the two would leave the probe in the user's folder)
        try:
            fd, probe = tempfile.mkstemp(prefix=".lfsf-probe.", dir=folder)
        except OSError as exc:  # (/proc answers "No such file or directory")
            return "no file can be made there" if exc.errno == errno.ENOENT else exc.strerror or str(exc)
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(probe)
    return ""


def _check_names(out: Path, names) -> None:
    for name in names:
        if (out / name).is_dir():
            raise ValueError(f"{out / name}: is a folder; {name} cannot be written there")


def refuse_replacing_inputs(out: str | os.PathLike, names, inputs, option: str = "--out") -> None:
    """Before any work: none of the files ``names`` to be written into the folder ``out``
    may be one of the files ``inputs`` (paths; folders and None are passed over), directly
    or through a symbolic link there: the results would replace what they were made from
    (a light field named sceneflow.npz, a ground truth disp1.pfm of an earlier result).

    Raises
    ------
    ValueError
        Naming the output and the input it would replace.
    """
    outputs = [Path(out) / name for name in names]
    for path in inputs:
        if path is None or not os.path.isfile(path):
            continue
        # the same file: by name (resolved), or by the file system's own account of it (a
        # name in another case on a file system that ignores case, a hard link)
        output = next((o for o in outputs if os.path.realpath(o) == os.path.realpath(path)
                       or (os.path.exists(o) and os.path.samefile(o, path))), None)
        if output is None:
            continue
        if os.path.abspath(output) == os.path.abspath(path):
            raise ValueError(f"{path}: read by this run, and the results would replace it (they write "
                             f"{output.name} into {out}); choose another {option}")
        if os.path.islink(output):
            raise ValueError(f"{output}: a link to {os.path.realpath(path)}, which this run reads ({path}); the "
                             f"results would be written through it: choose another {option}")
        raise ValueError(f"{output}: the same file as {path}, which this run reads; the results would replace "
                         f"it: choose another {option}")


def output_file(path: str | os.PathLike) -> Path:
    """``path`` as a file to write, checked before any work (nothing is made): not a
    folder, and no file where its folder should be (:func:`output_folder`)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a file to write")
    try:
        output_folder(path.parent, create=False)
    except ValueError as exc:  # (the file named, and why its folder cannot hold it)
        said = str(exc)
        prefix = f"{path.parent}: cannot write results there: "
        raise ValueError(f"{path}: cannot be written: {said.removeprefix(prefix)}") from None
    return path


def is_special_file(path: Path) -> bool:
    """Whether ``path`` is there but neither a file nor a folder: a named pipe or a device."""
    return path.exists() and not path.is_file() and not path.is_dir()


def not_a_file(path: Path) -> str:
    """What is at ``path`` where a file was looked for and is not there: "a link to nothing
    (or a loop of links)", "a folder", or "not a regular file" (a pipe, a device)."""
    if path.is_symlink() and not path.exists():
        return "a link to nothing (or a loop of links)"
    return "a folder" if path.is_dir() else "not a regular file"


def refuse_special_file(path: Path) -> None:
    """A ValueError for a path that is there but neither a file nor a folder: reading a
    named pipe waits for a writer, and a device (/dev/zero) may never end."""
    if is_special_file(path):
        raise ValueError(f"{path}: not a regular file (a named pipe or a device would be read forever)")


def read_capped(path: Path, most: int, what: str) -> bytes:
    """The bytes of ``path``, of which there may be at most ``most``: a named pipe or
    ``/dev/stdin`` is read as a file (``--config <(…)``), and ``/dev/zero``, which had been
    read for ever, ends in a ValueError saying the file is too long to be ``what``."""
    with open(path, "rb") as f:
        data = f.read(most + 1)
    if len(data) > most:
        raise ValueError(f"{path}: more than {most >> 20} MB, too long for {what}")
    return data


def file_name(path, what: str = "a file name") -> Path:
    """``path`` (str or os.PathLike) as a Path; a ValueError naming what was given else
    (None, a number, bytes: pathlib's TypeError had said nothing of the argument; "", which
    pathlib takes for the current folder)."""
    if not isinstance(path, (str, os.PathLike)) or isinstance(os.fspath(path), bytes):
        raise ValueError(f"expected {what} (str or path), got {type(path).__name__} {path!r}")
    if os.fspath(path) == "":
        raise ValueError(f"expected {what}, got an empty one")
    return Path(path)


def resolved(path: str | os.PathLike) -> Path:
    """``path`` with its links followed, absolute: :meth:`Path.resolve` without its
    RuntimeError on a loop of links (Python < 3.13; a loop stays as it is, and fails
    where it is read, with a message of its own)."""
    return Path(os.path.realpath(path))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; rename it onto ``path`` on success.

    ``suffix`` is the temporary file's ending (default: the target's own), which matters to
    writers that pick the format from the name (imageio, ``np.savez``). On any exception the
    temporary file is removed and the target is left as it was. A symbolic link is written
    through (the file it points to is replaced, the link kept); a target that is neither a
    file nor missing (``/dev/stdout``, a named pipe) is yielded itself, to write in place.
    """
    if not os.fspath(path):
        raise ValueError("an empty file name")
    path = Path(path)
    if is_special_file(path):                    # a device or a pipe (/dev/stdout)
        try:
            yield path
        except OSError as exc:  # (/dev/full's "No space left on device" named no file)
            raise _named(exc, path) from exc
        return
    if path.is_symlink():                        # the link stays; what it points to is written
        path = Path(os.path.realpath(path))
    if path.is_dir():
        raise ValueError(f"{path}: is a folder, not a file to write")
    output_folder(path.parent)                   # made if missing; no file where a folder goes
    suffix = path.suffix if suffix is None else suffix
    tmp_path = None
    try:
        # (the stem shortened: a target name near the 255-byte limit must still get a
        # temporary one; made inside the try, so that an interrupt right after leaves none)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem[:TEMP_STEM]}.", suffix=".part" + suffix, dir=path.parent)
        tmp_path = Path(tmp)
        os.close(fd)
        try:
            yield tmp_path
        except OSError as exc:
            raise _named(exc, path, tmp_path) from exc
        # mkstemp makes the file private (0600); give it the mode a plain open() would.
        os.chmod(tmp_path, 0o666 & ~_umask())
        replace(tmp_path, path)
    except BaseException:
        if tmp_path is not None:
            with contextlib.suppress(FileNotFoundError):
                tmp_path.unlink()
        raise


#: Tries of :func:`replace` (Windows: a file that a viewer, a virus scanner or the search
#: indexer holds open for a moment cannot be replaced; elsewhere one try).
REPLACE_TRIES = 6 if os.name == "nt" else 1


def replace(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """:func:`os.replace`, tried again a few times over about 3 s where Windows refuses it
    (PermissionError: the target or source held open by another process for a moment)."""
    import time

    for attempt in range(REPLACE_TRIES):
        try:
            os.replace(src, dst)
            return
        except PermissionError:
            if attempt == REPLACE_TRIES - 1:
                raise
            time.sleep(0.1 * 2 ** attempt)


def _named(exc: OSError, path: Path, tmp: Path | None = None) -> OSError:
    """The same error naming ``path``, what was being written, where it names no file (a
    full disk's ``[Errno 28] No space left on device`` names none) or names the temporary
    ``tmp`` or a file inside it (as its place under ``path``); else ``exc`` itself."""
    if exc.errno is None:
        return exc
    name = exc.filename
    if name is None:
        name = path
    elif tmp is not None and (Path(name) == tmp or tmp in Path(name).parents):
        name = path if Path(name) == tmp else path / Path(name).relative_to(tmp)
    else:
        return exc
    return type(exc)(exc.errno, exc.strerror or str(exc), os.fspath(name))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def json_bytes(obj, indent: int = 2, default=None) -> bytes:
    """``obj`` as strict JSON text with a final newline: NaN and ±inf, which JSON lacks
    (``json`` would write ``NaN``, ``Infinity``, which strict readers refuse), as null;
    numpy floats as floats. ``default`` as :func:`json.dumps` takes it."""
    import json
    import math

    import numpy as np

    def finite(x):
        if isinstance(x, (float, np.floating)):
            x = float(x)
            return x if math.isfinite(x) else None
        if isinstance(x, dict):
            return {k: finite(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [finite(v) for v in x]
        return x

    return (json.dumps(finite(obj), indent=indent, allow_nan=False, default=default) + "\n").encode()


def write_json_atomic(path: str | os.PathLike, obj, indent: int = 2, default=None) -> None:
    """Write ``obj`` to ``path`` as strict JSON (:func:`json_bytes`), atomically."""
    write_bytes_atomic(path, json_bytes(obj, indent=indent, default=default))


def savez_atomic(path: str | os.PathLike, compressed: bool = False, **arrays) -> None:
    """``np.savez`` (or ``savez_compressed``) to ``path`` atomically."""
    import numpy as np

    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            (np.savez_compressed if compressed else np.savez)(f, **arrays)


@contextlib.contextmanager
def interrupts_held():
    """Hold Ctrl-C (SIGINT), SIGTERM and SIGHUP back while the body runs, for the moves that put a
    set of outputs in place: an interrupt between two of them would leave a mix of an old
    set and a new one. A signal that comes meanwhile is delivered when the body ends.

    The handlers are swapped for ones that only note the signal. (Masking the signals
    with ``pthread_sigmask`` is not enough: it masks the calling thread only, and the
    kernel hands a process-wide signal to any other thread, such as a worker of the
    CPU launch pool, whose C handler then raises KeyboardInterrupt in the main thread
    all the same.) Handlers can only be set from the main thread; elsewhere the body
    runs unguarded, as Python delivers signals to the main thread only. A signal that
    was ignored stays ignored."""
    import signal
    import threading

    from lfsf._errors import ending_signals

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    old: dict = {}
    try:
        # (installed one by one inside the try, and restored each in a finally of its own:
        # a signal whose handler raises between two of these calls leaves none swapped)
        for s in (*ending_signals(), signal.SIGINT):
            if signal.getsignal(s) not in (signal.SIG_IGN, None):
                old[s] = signal.signal(s, lambda signum, frame: caught.append(signum))
        yield
    finally:
        _restore(list(old.items()))
        # SIGTERM (SIGHUP) first, where both came: the first one delivered ends the unwinding
        for s in sorted(set(caught), key=lambda s: s == signal.SIGINT):
            signal.raise_signal(s)


def _restore(handlers: list) -> None:
    """Put back each (signal, handler) of ``handlers``, the rest even if a signal's
    handler raises after the first."""
    import signal

    if handlers:
        (s, handler), rest = handlers[0], handlers[1:]
        try:
            signal.signal(s, handler)
        finally:
            _restore(rest)


#: The start of the name of :func:`file_set`'s temporary folder, followed by this
#: machine's (:func:`_host`) and the writing process's id (``.lfsf-set.HOST-PID.XXXXXXXX``).
SET_PREFIX = ".lfsf-set."


def _host() -> str:
    """This machine, as 12 hex digits of a hash of its full name (a cut-down name made
    two machines one: ``ip-10-0-1-23…`` and ``ip-10-0-12-3…``)."""
    import hashlib
    import socket

    return hashlib.sha1(socket.gethostname().encode("utf-8", "surrogateescape")).hexdigest()[:12]


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this machine; True off POSIX, where it cannot be
    asked (Windows' os.kill ends the process whatever the signal)."""
    if os.name != "posix":
        return True
    try:
        os.kill(pid, 0)  # (signal 0: only whether the process is there)
    except ProcessLookupError:
        return False
    except (OSError, OverflowError):  # there, another user's; or no process id at all
        return True
    return True


def gone(pid: int, host: str | None = None) -> bool:
    """Whether the process ``pid`` of the machine ``host`` (:func:`_host`'s digits; None:
    this machine) is known to be gone: a process of this machine, not this one, that no
    longer runs. Never another machine's, nor any off POSIX (:func:`_alive`). What the
    temporary folders of :func:`file_set`, of ``lfsf batch``'s pairs and of Warp's
    builds are asked before they are removed."""
    return (host is None or host == _host()) and pid != os.getpid() and not _alive(pid)


def dead_set(path: Path) -> bool:
    """Whether ``path`` is a temporary folder of :func:`file_set` made by a process of this
    machine that is gone (killed outright: SIGKILL, the out-of-memory killer, a power
    cut). False for a live process's, another machine's (a shared file system), any of
    another form, and anything off POSIX, where a process cannot be asked whether it is
    there. (Containers that share a host name but not their process ids would see each
    other's as gone: give them their own output folders.)"""
    made = re.fullmatch(re.escape(SET_PREFIX) + r"([0-9a-f]{12})-(\d+)\..+", path.name)
    return made is not None and gone(int(made[2]), made[1]) and path.is_dir()


def remove_dead_sets(out: Path) -> None:
    """Remove the temporary folders in ``out`` that :func:`dead_set` finds, which nothing
    else would remove."""
    import shutil

    with contextlib.suppress(OSError):
        for path in Path(out).glob(f"{SET_PREFIX}*"):
            if dead_set(path):
                shutil.rmtree(path, ignore_errors=True)


def folders_to_make(path) -> list[Path]:
    """The folders that making ``path`` (with its parents) creates, innermost first, to
    remove again if what was to go in them fails: those of its absolute, normalised form
    (``new/../existing`` names ``existing``, which exists: by the path as typed it had been
    listed, and an empty folder of the user's removed)."""
    path = Path(os.path.abspath(path))
    return [p for p in (path, *path.parents) if not os.path.lexists(p)]


def remove_made_folders(made: list[Path]) -> None:
    """Remove the folders :func:`folders_to_make` listed (innermost first) where a failure
    left them empty; the first that is not (or cannot go) stops it, as every folder above
    holds it."""
    for folder in made:
        try:
            folder.rmdir()
        except OSError:
            break


def stale_picture(out, picture: str, marker: str) -> tuple[str, ...]:
    """``(picture,)`` where ``out`` holds an earlier set's picture, known by the set's
    ``marker`` file beside it, which a new set without a picture of its own removes with
    the rest it replaces; () otherwise: a picture of that name of the user's own stays."""
    out = Path(out)
    return (picture,) if (out / picture).is_file() and (out / marker).is_file() else ()


def _keep_copy(path: Path, copy: Path) -> None:
    """``copy`` made to hold what the file ``path`` (or the file a link there names) holds
    now: a hard link where the file system allows one (nothing is copied), else a copy."""
    import shutil

    try:
        os.link(os.path.realpath(path), copy)
    except OSError:  # (no hard links there: FAT, some network file systems; or a file we may not link)
        shutil.copy2(path, copy)


def _put_in_place(out: Path, tmp: Path, names: list, stale: list) -> None:
    """Move the files ``names`` from ``tmp`` into ``out`` and remove the files ``stale``
    (an earlier set's) from it, all or nothing. Every file to be replaced is first kept
    (:func:`_keep_copy`, in ``tmp``) and every file removed is moved there, so that where a
    move fails (a file that cannot be replaced: immutable, another user's, open
    elsewhere) every earlier file is put back before the error, which names the file in
    ``out``. A symbolic link in the place of a file stays; the file it names is
    replaced."""
    import shutil

    kept = tmp / ".earlier"
    kept.mkdir()
    earlier: dict = {}  # name → its kept copy
    placed: list = []
    removed: list = []  # (name, where it went)
    name = None
    try:
        for k, name in enumerate(names):
            if (out / name).is_file():  # (through a link too)
                _keep_copy(out / name, kept / str(k))
                earlier[name] = kept / str(k)
        for name in names:
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            if (out / name).is_symlink():  # the link stays; the file it names is replaced
                with atomic_path(out / name) as through:
                    shutil.copyfile(tmp / name, through)
            else:
                replace(tmp / name, out / name)
            placed.append(name)  # (each move is whole or not at all)
        for k, name in enumerate(stale):
            replace(out / name, kept / f"stale-{k}")  # (removed with the temporary folder)
            removed.append((name, kept / f"stale-{k}"))
    except OSError as exc:
        back = True  # every earlier file put back
        for done, at in reversed(removed):
            try:
                replace(at, out / done)
            except OSError:
                back = False
        for done in reversed(placed):
            try:
                if (out / done).is_symlink() and done in earlier:
                    with atomic_path(out / done) as through:
                        shutil.copyfile(earlier[done], through)
                elif (out / done).is_symlink():  # (it named no file before)
                    os.unlink(os.path.realpath(out / done))
                elif done in earlier:
                    replace(earlier[done], out / done)
                elif os.path.lexists(out / done):
                    os.unlink(out / done)
            except OSError:
                back = False
        what = ("nothing was replaced: the earlier files are as they were" if back
                else "some of the earlier files could not be put back")
        raise OSError(exc.errno, f"{exc.strerror or exc} ({what})", os.fspath(out / name)) from exc


@contextlib.contextmanager
def file_set(out: Path, names, stale=()):
    """A temporary folder inside ``out`` to write the files ``names`` (paths relative to
    ``out``) into; on success they are moved into place together, with Ctrl-C held back
    meanwhile (:func:`interrupts_held`), so that a failure or an interrupt leaves either
    none of them or all of them, never a mix with an earlier set. The files ``stale`` (an
    earlier set's that this one does not replace) are removed in the same step. The temporary folders
    of killed processes are removed first (:func:`remove_dead_sets`). Existing folders in
    their place are refused before anything is written. A symbolic link in the place of
    a file is written through, as :func:`atomic_path` does: the link stays and the file
    it names is replaced. The folders made for ``out`` are removed again where the set
    fails."""
    import shutil

    out = Path(out)
    made = folders_to_make(out)  # (removed again if the set fails)
    tmp = None
    done = False
    try:
        out.mkdir(parents=True, exist_ok=True)
        _check_names(out, names)
        remove_dead_sets(out)
        tmp = Path(tempfile.mkdtemp(prefix=f"{SET_PREFIX}{_host()}-{os.getpid()}.", dir=out))
        try:
            yield tmp
        except OSError as exc:
            raise _named(exc, out, tmp) from exc
        with interrupts_held():
            _put_in_place(out, tmp, list(names), [n for n in stale if (out / n).is_file() or (out / n).is_symlink()])
            done = True
            # (the earlier set's files, kept aside in it until now: a signal during this had
            # cut it short and left the hidden folder with them, a helper's 10 runs of 12)
            shutil.rmtree(tmp, ignore_errors=True)
            tmp = None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if not done:  # (an interrupted or failed set had left the folders made for it, empty)
            remove_made_folders(made)
