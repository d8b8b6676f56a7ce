"""One writer per contacts file: an exclusive lock on ``OUT.h5.lock`` for the whole run.

A run that writes ``OUT.h5`` owns three names beside it: ``OUT.h5.partial``
(its committed frames), ``OUT.h5.tmp`` (the file being assembled) and
``OUT.h5`` itself.  Two runs writing them at once can each see the other's
segments, assemble a file the other is still extending, or remove what the
other is about to open.  :func:`output_lock` takes ``flock(LOCK_EX)`` on
``OUT.h5.lock`` without waiting, so the second run is refused before it
reads a frame or touches any of those names.

The lock belongs to the open file, not to the name: when the holder dies
(killed, out of memory, power lost on a local disk) the operating system
releases it, and the next run takes it and resumes the partial run.  A
holder that finishes removes the lock file while it still holds the lock; a
run that was waiting on the removed file notices that the name now points
elsewhere (or nowhere) and tries again on the new file, so two runs never
hold locks on two different files of the same name.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import time

__all__ = ["OutputBusyError", "lock_path", "output_lock"]


class OutputBusyError(OSError):
    """Another run holds the lock of this output: it is being written now."""


def lock_path(output) -> str:
    """The lock file of contacts file ``output``: ``output + '.lock'``."""
    return os.fspath(output) + ".lock"


def _holder(fd) -> str:
    """``' (pid N on HOST)'`` as the holder wrote it, or ``''``.

    A holder writes its line right after it takes the lock; a run refused in
    between reads the file again for up to a tenth of a second."""
    for _ in range(20):
        try:
            text = os.pread(fd, 200, 0).decode("utf-8", "replace")
        except OSError:
            return ""
        words = text.split()
        if text.endswith("\n") and len(words) >= 2 and words[0].isdigit():
            host = words[1]
            return f" (pid {words[0]}{'' if host == socket.gethostname() else ' on ' + host})"
        time.sleep(0.005)
    return ""


def _acquire(output, path):
    import fcntl

    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            who = _holder(fd)
            os.close(fd)
            raise OutputBusyError(
                f"{output} is being written by another run{who}; wait for it to finish, or "
                f"write to another file (lock {path})") from None
        except BaseException:
            os.close(fd)
            raise
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder finished and removed this file: lock the new one
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()} {socket.gethostname()}\n".encode(), 0)
    return fd


@contextlib.contextmanager
def output_lock(output, *, on_warning=None):
    """Hold the exclusive lock of contacts file ``output`` inside the ``with`` block.

    Parameters
    ----------
    output : str or os.PathLike
        The contacts file; the lock is ``output + '.lock'`` (removed on exit).
    on_warning : callable, optional
        Told, with one line, when the file system cannot lock (the run goes on
        unlocked); default :func:`warnings.warn`.

    Raises
    ------
    OutputBusyError
        Another run holds the lock; raised at once, without waiting.

    Examples
    --------
    >>> import os, tempfile
    >>> out = os.path.join(tempfile.mkdtemp(), "c.h5")
    >>> with output_lock(out):
    ...     try:
    ...         with output_lock(out):
    ...             pass
    ...     except OutputBusyError as exc:
    ...         print("refused:", "being written by another run" in str(exc))
    refused: True
    >>> os.path.exists(out + ".lock")
    False
    """
    output = os.fspath(output)
    path = lock_path(output)
    try:
        fd = _acquire(output, path)
    except (ImportError, OSError) as exc:
        if isinstance(exc, OutputBusyError) or (
                isinstance(exc, OSError) and exc.errno not in (errno.ENOLCK, errno.EOPNOTSUPP,
                                                               errno.ENOSYS)):
            raise
        message = (f"cannot lock {path} ({exc}); the run goes on without a lock: do not "
                   f"start a second writer of {output} until it ends")
        if on_warning is None:
            import warnings

            warnings.warn(message, UserWarning, stacklevel=3)
        else:
            on_warning(message)
        yield
        return
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(path)  # still locked: a waiting run sees the name is gone and retries
        os.close(fd)
