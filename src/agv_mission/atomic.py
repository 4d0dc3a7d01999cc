"""Safe file I/O: atomic writes, and reads of input files that refuse what is not one.

Atomic writes: a reader sees the old file or the new one, never half of one.

The write goes to a temporary file beside the target, which is fsynced and renamed over
it. What a user expects of an ordinary write is kept: a symlink is followed (its target
gets the new content, the link stays a link), an existing file keeps its permission bits,
and a new file gets the mode the umask gives (``0666 & ~umask``), not ``mkstemp``'s 0600.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
from pathlib import Path

NEW_FILE_MODE = 0o666  # the kernel applies the umask, as open(path, "w") does
MAX_INPUT_BYTES = 4 * 1024 * 1024  # a mission, world, rooms, robot or recorder file


class InputFileError(OSError):
    """An input file that cannot be read as one: missing, a directory, a FIFO or a device,
    too large. ``str()`` is a sentence without the path (callers name the file)."""

    def __init__(self, message: str, missing: bool = False) -> None:
        super().__init__(message)
        self.message = message
        self.missing = missing

    def __str__(self) -> str:
        return self.message


def read_input_bytes(path: str | os.PathLike, limit: int = MAX_INPUT_BYTES) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes, checked before reading.

    A directory, a FIFO or a device (``/dev/zero``) is refused without opening it, so
    nothing blocks or reads forever.
    """
    try:
        st = os.stat(path)
    except FileNotFoundError as exc:
        raise InputFileError(f"cannot read: {exc.strerror}", missing=True) from None
    except (OSError, ValueError) as exc:
        raise InputFileError(f"cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputFileError("cannot read: Is a directory")
    if not stat.S_ISREG(st.st_mode):
        kind = "a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device or socket"
        raise InputFileError(f"cannot read: {kind}, not a regular file")
    if st.st_size > limit:
        raise InputFileError(
            f"too large: {st.st_size} bytes; input files are limited to {_size(limit)}"
        )
    try:
        with open(path, "rb") as f:
            data = f.read(limit + 1)
    except OSError as exc:
        raise InputFileError(f"cannot read: {exc.strerror or exc}") from None
    if len(data) > limit:  # grew since the stat
        raise InputFileError(f"too large: input files are limited to {_size(limit)}")
    return data


def input_path(spec: str | os.PathLike, base_dir: str | os.PathLike) -> Path:
    """A file a document names: ``~`` expanded, and a relative path taken from the
    document's own directory ``base_dir`` (not from where the program runs)."""
    path = Path(spec).expanduser()
    return path if path.is_absolute() else Path(base_dir) / path


def read_input_text(path: str | os.PathLike, limit: int = MAX_INPUT_BYTES) -> str:
    """:func:`read_input_bytes` decoded as UTF-8 (``UnicodeDecodeError`` if it is not)."""
    return read_input_bytes(path, limit).decode("utf-8")


def _size(n: int) -> str:
    return f"{n / 1024 / 1024:g} MB" if n >= 1024 * 1024 else f"{n} bytes"


def write_target(path: str | os.PathLike) -> Path:
    """The file a write to ``path`` changes: the end of its symlink chain, if it is one."""
    path = Path(path)
    if path.is_symlink():
        return Path(os.path.realpath(path))
    return path


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to a temporary file beside ``path``, fsync it, rename it over ``path``,
    and fsync the directory so that the rename survives a power cut too. Returns the path
    written (a symlink's target)."""
    path = write_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode: int | None = stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        mode = None
    fd, tmp = _create_temporary(path)
    try:
        with os.fdopen(fd, "wb") as f:
            if mode is not None:
                os.fchmod(f.fileno(), mode)
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_directory(path.parent)
    return path


def _create_temporary(path: Path) -> tuple[int, Path]:
    """A new file beside ``path``, created with the umask's mode (``O_EXCL``: never shared)."""
    for _ in range(100):
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, NEW_FILE_MODE), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"cannot create a temporary file beside {path}")


def _fsync_directory(directory: Path) -> None:
    """Make the rename itself durable (best effort: not every platform opens directories)."""
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))
