"""Atomic file output: write to a temporary file in the target directory, then rename over the target; and an
exclusive lock on an output directory, so that two runs never write into one directory at once.

Temporary files are named ``.<target name>.<random><suffix>`` beside their target. A process killed outright
(SIGKILL, power loss) cannot delete its own; :func:`remove_stale_temps` clears them, and is safe to call only while
holding the directory's lock (:func:`locked_dir`), when no other writer can own one.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import glob
import os
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes", "locked_dir", "DirectoryLocked",
           "remove_stale_temps", "LOCK_NAME"]

LOCK_NAME = ".lock"


class DirectoryLocked(ValueError):
    """Another process holds the output directory's lock (a user error: one line, naming the directory and pid)."""


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``, on error delete it.

    An interrupted run (exception, Ctrl-C) therefore never leaves a half-written ``path``. ``suffix`` defaults to
    the target's suffix (some writers, e.g. ``np.savez``, append one otherwise).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix if suffix is not None else path.suffix,
                               dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp creates 0600; give the file the permissions open() would
        os.replace(tmp_path, path)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


@contextlib.contextmanager
def locked_dir(directory: str | Path) -> Iterator[Path]:
    """Hold an exclusive lock on ``directory`` (created if needed) for the ``with`` block: ``directory/.lock``,
    locked with ``flock`` and holding this process's pid. Another process asking for the same lock gets
    :class:`DirectoryLocked` at once, naming the holder's pid, instead of racing it for the same files. The kernel
    drops the lock when its holder dies, even by SIGKILL, so a left-over lock file never blocks a later run; the file
    is removed on release."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / LOCK_NAME
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EAGAIN, errno.EACCES):
                raise
            try:
                holder = path.read_text().strip() or "?"
            except OSError:
                holder = "?"
            raise DirectoryLocked(f"{directory}: another run (pid {holder}) is writing into this directory; wait "
                                  "for it to finish or choose another output directory") from None
        try:                           # the file we locked may have been unlinked by a holder releasing it: retry
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield path
    finally:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        os.close(fd)


def remove_stale_temps(directory: str | Path, names: Iterable[str]) -> list[Path]:
    """Delete the temporary files :func:`atomic_path` left in ``directory`` for the targets ``names`` (a process
    killed outright cannot delete its own; module docstring). Call it only while holding :func:`locked_dir`. Returns
    what was removed."""
    removed = []
    for name in names:
        for tmp in glob.glob(os.path.join(glob.escape(str(directory)), f".{glob.escape(name)}.*")):
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
                removed.append(Path(tmp))
    return removed
