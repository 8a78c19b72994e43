"""Atomic file writing: a result file is either complete or absent, never partial.

:func:`atomic_path` is the one mechanism (a temporary file beside the target, renamed onto it);
:func:`write_bytes_atomic` (meshes) and :func:`write_json` are built on it.
"""

from __future__ import annotations

import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from ..errors import MeshFileError

__all__ = ["atomic_path", "write_bytes_atomic", "write_json"]


@contextmanager
def atomic_path(path):
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``.

    The temporary name keeps the final suffix so that writers choosing a format by extension
    (trimesh, numpy) still work. On any exception the temporary file is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    # mkstemp makes the file private (0600); a result file gets the usual permissions instead
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def write_text(path, text: str) -> None:
    """Write ``text`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_json(path, obj) -> None:
    """Write ``obj`` as indented JSON atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2) + "\n")


def write_bytes_atomic(path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (usual umask permissions, nothing left on failure).

    Unlike :func:`atomic_path` the directory is not created: a missing directory or any OS
    failure is a one-line MeshFileError (an OSError) naming ``path``.
    """
    path = Path(path)
    if not path.parent.exists():
        raise MeshFileError(f"{path}: directory {path.parent} does not exist")
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
    except OSError as e:
        raise MeshFileError(f"{path}: cannot write: {e.strerror or e}") from None
