"""A training run's directory: the lock that keeps a second process out of it, the check of a
fresh or resumed run against its checkpoints, and ``run.json`` (the layout:
:mod:`agents.run.training`)."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
from collections.abc import Iterator

from agents.run import checkpoint
from agents.run.spec import RunSpec
from mjxrmp.atomic import atomic_write

#: The lock file of a run directory.
LOCK_FILE = ".lock"


class RunDirectoryInUseError(RuntimeError):
    """A run directory another process is training into."""


@contextlib.contextmanager
def lock_run_directory(out_dir: str) -> Iterator[None]:
    """Hold an exclusive ``fcntl.flock`` on ``<out_dir>/.lock`` (this process's id written in
    it) for the ``with`` block; :class:`RunDirectoryInUseError` naming the holder's process
    id if another process holds it. The lock goes with the process (``kill -9`` included)."""
    fd = os.open(os.path.join(out_dir, LOCK_FILE), os.O_RDWR | os.O_CREAT, 0o666)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "(unknown id)"
            raise RunDirectoryInUseError(
                f"{out_dir} is in use by process {holder} (another run trains into it); wait "
                "for it to end or choose another output directory") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)


def check_dir(out_dir: str, resume: bool) -> str:
    """Check ``out_dir`` against ``resume`` (a fresh run needs a directory without checkpoints,
    a resumed one a checkpoint); the checkpoint directory."""
    ckpt_dir = os.path.join(out_dir, "checkpoints")
    has_ckpt = checkpoint.latest_step(ckpt_dir) is not None
    if has_ckpt and not resume:
        raise FileExistsError(f"{out_dir} already holds a run; pass resume=True (--resume) to "
                              "continue it or choose another output directory")
    if resume and not has_ckpt:
        raise FileNotFoundError(f"resume=True but there is no checkpoint in {ckpt_dir}")
    return ckpt_dir


def write_spec(spec: RunSpec, out_dir: str) -> None:
    """``run.json`` (atomically)."""
    atomic_write(os.path.join(out_dir, "run.json"), json.dumps(spec.to_json(), indent=1).encode())


__all__ = ["LOCK_FILE", "RunDirectoryInUseError", "check_dir", "lock_run_directory",
           "write_spec"]
