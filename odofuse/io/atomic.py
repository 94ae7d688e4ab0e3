"""Atomic writing of files and whole folders, and claiming an output folder for one run.

:func:`os.replace` is atomic on POSIX and Windows within one file system, so a reader sees the
old file or the new one, never a half-written one. Every writer of odofuse (log folders,
trajectories, metrics, pictures, simulated logs) goes through :func:`atomic_write`.

A run folder is written whole (shared by ``odofuse run`` and ``odofuse batch``):
:func:`claim_folder` takes a lock file ``.<name>.lock`` (holding the pid) beside the folder, so a
second run into the same folder fails with a clear error; the outputs go to
:func:`temp_folder` ``.<name>.tmp-<id>`` beside it and :func:`publish` swaps it in. A killed run
leaves the previous complete folder (or, killed inside the swap, its ``.old-`` copy, which
:func:`clean_stale` puts back); :func:`clean_stale` removes what a crash left behind.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import uuid
from collections.abc import Callable
from pathlib import Path

from odofuse.errors import OdofuseError

_TMP_MARK = ".tmp-"
_OLD_MARK = ".old-"
_LOCK_SUFFIX = ".lock"
#: Folders this process holds (so that a nested claim of the same folder is a no-op).
_HELD: set[str] = set()


def atomic_write(path: str | Path, write: Callable[[str], None]) -> Path:
    """Call ``write(tmp_path)`` on a temporary file next to ``path``, then rename it to ``path``.

    The temporary file is deleted if ``write`` raises, and the exception propagates.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        # mkstemp creates the file 0600; give the output the permissions open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""

    def write(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())

    return atomic_write(path, write)


# ----------------------------------------------------------------------- whole folders
def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by another user
        return True
    try:  # Linux: a killed process not yet reaped by its parent is a zombie, not a run
        stat = Path(f"/proc/{pid}/stat").read_text(encoding="ascii", errors="replace")
    except OSError:
        return True
    return stat.rpartition(")")[2].split()[:1] != ["Z"]


def lock_path(folder: str | Path) -> Path:
    """The lock file of ``folder``: ``.<name>.lock`` beside it."""
    folder = Path(folder)
    return folder.with_name(f".{folder.name}{_LOCK_SUFFIX}")


def _create_lock(lock: Path) -> bool:
    """Create ``lock`` holding this process's pid, atomically; False when it exists.

    The pid is written to a private file first and hard-linked to ``lock`` (which fails when
    ``lock`` exists), so no other run ever reads the lock empty and takes it for stale.
    """
    fd, tmp = tempfile.mkstemp(prefix=f"{lock.name}.", suffix=".new", dir=lock.parent)
    try:
        with os.fdopen(fd, "w", encoding="ascii") as fh:
            fh.write(f"{os.getpid()}\n")
        os.chmod(tmp, 0o644)
        try:
            os.link(tmp, lock)
        except FileExistsError:
            return False
        return True
    finally:
        os.unlink(tmp)


def _take_stale(lock: Path, pid: int) -> None:
    """Remove ``lock`` left by the dead run ``pid``, unless another run took it over meanwhile.

    The lock is renamed aside (atomic) and read again: a lock that now holds another pid was
    created after ours was read, and is put back.
    """
    aside = lock.with_name(f"{lock.name}.stale-{uuid.uuid4().hex[:8]}")
    try:
        os.replace(lock, aside)
    except FileNotFoundError:
        return
    try:
        now = int(aside.read_text(encoding="ascii").strip() or 0)
    except (OSError, ValueError):
        now = 0
    if now != pid and now and _pid_alive(now):
        with contextlib.suppress(FileExistsError):
            os.link(aside, lock)
    aside.unlink()


@contextlib.contextmanager
def claim_folder(folder: str | Path):
    """Hold ``folder`` for this run: a second run (another process) into it is an error.

    The lock file holds the owner's pid; a lock whose process is gone (a killed run) is
    taken over. Nested claims of the same folder by this process are no-ops.

    Raises
    ------
    OdofuseError
        When a live process holds the folder.
    """
    folder = Path(folder).absolute()
    key = str(folder)
    if key in _HELD:
        yield folder
        return
    lock = lock_path(folder)
    lock.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(3):
        if _create_lock(lock):
            break
        try:
            pid = int(lock.read_text(encoding="ascii").strip() or 0)
        except FileNotFoundError:
            continue  # released between our attempt and the read: try again
        except (OSError, ValueError):
            pid = 0
        if pid and _pid_alive(pid):
            raise OdofuseError(
                f"output folder {folder} is in use by another run (pid {pid}); "
                f"wait for it or choose another -o (lock file {lock})"
            ) from None
        _take_stale(lock, pid)
    else:  # pragma: no cover - a race lost three times in a row
        raise OdofuseError(f"cannot claim output folder {folder} (lock file {lock})")
    _HELD.add(key)
    try:
        yield folder
    finally:
        _HELD.discard(key)
        with contextlib.suppress(FileNotFoundError):
            lock.unlink()


def temp_folder(parent: str | Path, name: str) -> Path:
    """A fresh temporary folder ``.<name>.tmp-<id>`` inside ``parent`` (same file system)."""
    tmp = Path(parent) / f".{name}{_TMP_MARK}{uuid.uuid4().hex[:8]}"
    tmp.mkdir(parents=True)
    return tmp


def publish(tmp: Path, final: Path) -> None:
    """Rename the complete folder ``tmp`` to ``final``, replacing an earlier run's folder.

    An earlier ``final`` is first renamed aside (``.<name>.old-<id>``) and removed after; at
    every instant ``final`` is either absent (its old copy then beside it), the old complete
    run or the new one.
    """
    old = None
    if final.exists():
        old = final.with_name(f".{final.name}{_OLD_MARK}{uuid.uuid4().hex[:8]}")
        os.replace(final, old)
    os.replace(tmp, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _stale_name(entry: str) -> tuple[str, str] | None:
    """``(name, mark)`` of a temporary ``.<name>.tmp-<id>`` / ``.<name>.old-<id>`` entry."""
    for mark in (_TMP_MARK, _OLD_MARK):
        head, sep, _ = entry.rpartition(mark)
        if sep and head.startswith(".") and len(head) > 1:
            return head[1:], mark
    return None


def clean_stale(parent: str | Path, name: str | None = None) -> list[Path]:
    """Remove temporary folders a killed run left in ``parent`` (those of ``name``, or all).

    A run killed inside :func:`publish` leaves its folder renamed aside: when a folder is
    absent but its ``.old-`` copy is there, the copy is put back first. Returns what was
    removed.
    """
    parent = Path(parent)
    if not parent.is_dir():
        return []
    removed = []
    for p in sorted(parent.iterdir()):
        found = _stale_name(p.name)
        if found is None or (name is not None and found[0] != name):
            continue
        final = parent / found[0]
        if found[1] == _OLD_MARK and not final.exists():
            os.replace(p, final)
            continue
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed
