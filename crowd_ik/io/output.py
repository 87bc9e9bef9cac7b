"""Atomic, no-clobber output files: the one way every writer in crowd_ik puts a file on disk.

Rules (DESIGN.md, "Command line"): no output is overwritten without `force`; each is written to
a hidden temporary name in the same folder with the same suffix (writers that pick a format by
suffix - ffmpeg, OpenCV, matplotlib, trimesh, numpy - still see `.mp4`, `.png`, `.glb`, `.npz`)
and renamed into place only when complete. An interrupted or failed write leaves no temporary
file behind and the old file, if any, untouched.

    with atomic_path("out/run.json", force=args.force) as tmp:
        tmp.write_text(...)          # or fig.savefig(tmp), scene.export(tmp), np.savez(tmp, ...)
"""

from __future__ import annotations

import contextlib
import enum
import errno
import json
import math
import os
import secrets
from pathlib import Path
from typing import Any, Iterator

import numpy as np

__all__ = [
    "check_writable",
    "check_writable_dir",
    "atomic_path",
    "make_temp_path",
    "publish",
    "write_bytes",
    "write_text",
    "write_json",
    "is_dir_target",
    "make_parents",
    "remove_folders",
    "named_os_error",
]


def is_dir_target(path: str | os.PathLike) -> bool:
    """True when `path` names a folder output: it ends in '/' (or os.sep) or is an existing folder."""
    text = os.fspath(path)
    return text.endswith(("/", os.sep)) or Path(text).is_dir()


def _check_parent(path: Path) -> None:
    """Refuse a parent that is a file or an unwritable folder; a missing parent is fine (created later)."""
    ancestor = path.parent
    while not ancestor.exists():
        if ancestor.is_symlink():  # a dangling link: mkdir would fail on it
            raise NotADirectoryError(f"{path}: parent {ancestor} is a broken link")
        if ancestor == ancestor.parent:
            break
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise NotADirectoryError(f"{path}: parent {ancestor} is not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ValueError(f"{path}: folder {ancestor} is not writable")


def check_writable(path: str | os.PathLike, force: bool = False) -> Path:
    """Check that a file may be written at `path`; return it as a Path. Creates nothing.

    Raises FileExistsError("PATH exists") for an existing file without `force`,
    IsADirectoryError when `path` is (or is spelled as) a folder, NotADirectoryError when a parent
    is a file, ValueError when the nearest existing parent folder is not writable.
    """
    text = os.fspath(path)
    if not text:
        raise ValueError("output path is empty")
    if text.endswith(("/", os.sep)):
        raise IsADirectoryError(f"{text}: is a folder, a file name is expected")
    out = Path(text).expanduser()
    if out.is_dir():
        raise IsADirectoryError(f"{out}: is a folder, a file name is expected")
    _check_parent(out)
    if out.exists() or out.is_symlink():
        if not force:
            raise FileExistsError(f"{out} exists")
        if not (out.is_file() or out.is_symlink()):
            raise ValueError(f"{out}: exists and is not a regular file")
    return out


def check_writable_dir(path: str | os.PathLike, force: bool = False) -> Path:
    """Check that a folder of output files (e.g. PNG frames) may be written at `path`.

    A missing folder is fine (created when written); an existing empty folder is fine; an existing
    non-empty folder needs `force`; an existing file at that name is refused (NotADirectoryError).
    """
    text = os.fspath(path)
    if not text:
        raise ValueError("output folder path is empty")
    out = Path(os.path.abspath(Path(text).expanduser()))  # "./" and "../" get a real name
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: exists and is not a folder")
    if out.is_dir():
        if not os.access(out, os.W_OK | os.X_OK):
            raise ValueError(f"{out}: folder is not writable")
        if not force and any(out.iterdir()):
            raise FileExistsError(f"{out}{os.sep} exists and is not empty")
    else:
        _check_parent(out)
    return out


def make_temp_path(final: Path, folder: bool = False) -> Path:
    """Create (empty) and return a unique hidden file - or folder - next to `final`, same suffix.

    Created with the usual permissions (0666 / 0777 less the umask), so the renamed output is
    not left private the way tempfile.mkstemp would leave it.
    """
    for _ in range(100):
        tmp = final.parent / f".{final.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}{'' if folder else final.suffix}"
        try:
            if folder:
                os.mkdir(tmp, 0o777)
            else:
                os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(f"{final}: could not create a unique temporary name in {final.parent}")


def publish(tmp: Path, final: Path, force: bool) -> None:
    """Move the finished `tmp` onto `final`: a replace with `force`, else a no-clobber link.

    Without force the rename is done with link() + unlink(), which fails if `final` appeared since
    the check (another process), so even that race never clobbers a file. Filesystems without hard
    links fall back to a checked replace.
    """
    if force:
        os.replace(tmp, final)
        return
    try:
        os.link(tmp, final)
    except FileExistsError:
        raise FileExistsError(f"{final} exists") from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
            raise
        if final.exists():
            raise FileExistsError(f"{final} exists") from None
        os.replace(tmp, final)
        return
    os.unlink(tmp)


def make_parents(folder: Path) -> list[Path]:
    """`mkdir -p folder`; return the folders this created, outermost first (for remove_folders)."""
    missing = []
    p = Path(folder)
    while not p.exists() and not p.is_symlink() and p != p.parent:
        missing.append(p)
        p = p.parent
    try:
        Path(folder).mkdir(parents=True, exist_ok=True)
    except BaseException:
        remove_folders(missing[::-1])
        raise
    return missing[::-1]


def remove_folders(created: list[Path]) -> None:
    """Remove the folders make_parents created, innermost first, where still empty: a failed or
    interrupted writer leaves no folder behind."""
    for folder in reversed(created):
        with contextlib.suppress(OSError):
            folder.rmdir()


def named_os_error(exc: OSError, final: Path) -> OSError:
    """The same OS error (errno, strerror) naming `final`, the output the user asked for, rather than
    a temporary name or none; an OSError without an errno (a message of ours) is returned as it is.
    (OSError(errno, ...) is of the errno's subclass: PermissionError, FileExistsError, ...)"""
    if exc.errno is None:
        return exc
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(final))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to `path` (hidden, unique, same suffix); publish it on success.

    Missing parent folders are created. On any exception - KeyboardInterrupt included - the
    temporary file is deleted, so are the parent folders this created, `path` is left as it was, and
    the exception propagates; an OSError (no space left, permission denied) is raised again naming
    `path`, with its errno and strerror. The writer may replace the temporary file (e.g. an encoder
    that recreates it) but must leave it a file.
    """
    final = check_writable(path, force)
    try:
        created = make_parents(final.parent)
    except OSError as exc:
        raise named_os_error(exc, final) from None
    try:
        tmp = make_temp_path(final)
    except OSError as exc:
        remove_folders(created)
        raise named_os_error(exc, final) from None
    try:
        yield tmp
        if not tmp.is_file():
            raise RuntimeError(f"{final}: the writer left no file at {tmp.name}")
        publish(tmp, final, force)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        remove_folders(created)
        if isinstance(exc, OSError):
            raise named_os_error(exc, final) from None
        raise


def write_bytes(path: str | os.PathLike, data: bytes, force: bool = False) -> Path:
    """Write `data` to `path` atomically without clobbering; return the final Path."""
    with atomic_path(path, force) as tmp:
        tmp.write_bytes(data)
    return Path(path).expanduser()


def write_text(path: str | os.PathLike, text: str, force: bool = False) -> Path:
    """Write `text` (UTF-8) to `path` atomically without clobbering; return the final Path."""
    return write_bytes(path, text.encode("utf-8"), force)


def _json_default(obj: Any) -> Any:
    """Make NumPy scalars and arrays, paths and Enum members JSON-serialisable."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating):
        return float(obj)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, enum.Enum):
        return obj.value
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _find_nonfinite(obj: Any, where: str = "$") -> str | None:
    """JSON-path-like location of the first NaN/inf in `obj`, or None."""
    if isinstance(obj, (float, np.floating)):
        return None if math.isfinite(obj) else where
    if isinstance(obj, np.ndarray) and obj.dtype.kind in "fc":
        bad = np.argwhere(~np.isfinite(obj))
        return f"{where}[{', '.join(map(str, bad[0]))}]" if bad.size else None
    if isinstance(obj, dict):
        for k, v in obj.items():
            found = _find_nonfinite(v, f"{where}.{k}")
            if found:
                return found
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            found = _find_nonfinite(v, f"{where}[{i}]")
            if found:
                return found
    return None


def write_json(path: str | os.PathLike, obj: Any, force: bool = False) -> Path:
    """Write `obj` as JSON (indent 2, keys in insertion order, trailing newline) atomically.

    NaN and infinities are refused with a ValueError naming the file and the offending key, since
    strict JSON readers (browsers, jq) reject them. NumPy scalars and arrays are converted.
    """
    bad = _find_nonfinite(obj)
    if bad:
        raise ValueError(f"{os.fspath(path)}: refusing to write a non-finite number at {bad}")
    text = json.dumps(obj, indent=2, allow_nan=False, default=_json_default) + "\n"
    return write_text(path, text, force)
