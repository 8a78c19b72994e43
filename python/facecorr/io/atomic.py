"""Atomic file writing: a result file is either complete or absent, never partial.

:func:`atomic_path` is the one mechanism (a temporary file beside the target, renamed onto it);
:func:`write_bytes_atomic` (meshes) and :func:`write_json` are built on it. :func:`atomic_paths`
writes several files as a group (all or none); :func:`check_output_paths` refuses, before any
work, outputs that cannot be written; :func:`remove_stale_temps` removes the temporaries a killed
process left beside a target.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path

from ..errors import FacecorrError, MeshFileError, OutputError

__all__ = ["atomic_path", "atomic_paths", "check_output_paths", "remove_stale_temps",
           "write_bytes_atomic", "write_json"]


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


def _same_key(path) -> str:
    return os.path.normcase(os.path.realpath(os.path.abspath(path)))


def _existing_ancestor(path: Path) -> Path:
    """The nearest existing ancestor of ``path`` (a parent that is a file stops the walk too)."""
    a = path.parent
    while not os.path.lexists(a) and a != a.parent:
        a = a.parent
    return a


def check_output_paths(outputs, *, inputs=()) -> None:
    """Refuse, before any work, outputs that cannot be written. Raises OutputError naming the path.

    ``outputs``: pairs (label, path), e.g. ``("-o", "r.ply")``; ``inputs``: paths that must not be
    overwritten. Refused: an existing folder as output, a parent that is a file, a folder without
    write permission, two outputs naming the same file, an output naming an input.
    """
    ins = {_same_key(p): Path(p) for p in inputs}
    seen = {}
    for label, p in outputs:
        p = Path(p)
        key = _same_key(p)
        if key in ins:
            raise OutputError(f"{p}: {label} would overwrite the input {ins[key]}")
        if key in seen:
            raise OutputError(f"{p}: given both as {seen[key]} and as {label}: they must be different files")
        seen[key] = label
        if p.is_dir():
            raise OutputError(f"{p}: is a folder ({label} needs a file name)")
        if os.path.lexists(p) and not p.is_file():
            raise OutputError(f"{p}: exists and is not a regular file ({label})")
        anc = _existing_ancestor(p)
        if not anc.is_dir():
            raise OutputError(f"{p}: cannot write there: {anc} is a file, not a folder")
        if not os.access(anc, os.W_OK | os.X_OK):
            raise OutputError(f"{p}: cannot write there: no permission to write in {anc}")


def _substitute(text: str, names: dict) -> str:
    for tmp, target in names.items():
        text = text.replace(tmp, target)
    return text


@contextmanager
def atomic_paths(*paths):
    """Yield one temporary path per target (beside it, same suffix); when the block succeeds they
    are all renamed onto their targets, on any exception all are removed (and the folders this
    created, if still empty): the targets are all written or none is.

    An OSError (a full disk, no permission, ...) becomes an OutputError naming the user's path,
    never the temporary one; a FacecorrError raised by a writer has temporary names replaced by
    the targets' names.
    """
    targets = [Path(p) for p in paths]
    tmps: list[Path] = []
    made: list[Path] = []
    current = targets[0] if targets else None
    try:
        try:
            umask = os.umask(0)
            os.umask(umask)
            for path in targets:
                current = path
                missing = []
                d = path.parent
                while not d.exists() and d != d.parent:
                    missing.append(d)
                    d = d.parent
                for d in reversed(missing):
                    d.mkdir()
                    made.append(d)
                fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
                os.close(fd)
                tmps.append(Path(tmp))
                os.chmod(tmp, 0o666 & ~umask)
        except OSError as e:
            raise OutputError(f"{current}: cannot write: {e.strerror or e}") from None
        names = {str(t): str(p) for t, p in zip(tmps, targets)}
        try:
            yield list(tmps)
        except FacecorrError as e:
            msg = _substitute(str(e), names)
            if msg == str(e):
                raise
            try:
                err = type(e)(msg)
            except Exception:  # noqa: BLE001 - an exception type with another signature
                err = OutputError(msg)
            raise err from None
        except OSError as e:
            who = names.get(str(getattr(e, "filename", "")), str(targets[0]))
            raise OutputError(f"{who}: cannot write: {_substitute(e.strerror or str(e), names)}") from None
        existed = [os.path.lexists(p) for p in targets]
        for i, (tmp, path) in enumerate(zip(tmps, targets)):
            try:
                os.replace(tmp, path)
            except OSError as e:
                # (rare: the temporaries sit beside their targets) take back the new files
                # renamed so far; a replaced older file cannot be restored
                for done, was_there in zip(targets[:i], existed[:i]):
                    if not was_there:
                        try:
                            os.unlink(done)
                        except OSError:
                            pass
                raise OutputError(f"{path}: cannot write: {e.strerror or e}") from None
    except BaseException:
        for tmp in tmps:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        for d in reversed(made):
            try:
                d.rmdir()
            except OSError:
                pass
        raise


def remove_stale_temps(path) -> int:
    """Remove the temporaries :func:`atomic_path` / :func:`atomic_paths` would make for ``path``
    (``.STEM.XXXXXXXX.SUFFIX`` beside it) that a killed process left behind. Returns how many."""
    path = Path(path)
    pattern = re.compile(rf"^\.{re.escape(path.stem)}\.[a-z0-9_]{{8}}{re.escape(path.suffix)}$")
    n = 0
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return 0
    for e in entries:
        if pattern.match(e.name) and e.is_file(follow_symlinks=False):
            try:
                os.unlink(e.path)
                n += 1
            except FileNotFoundError:
                pass
    return n
