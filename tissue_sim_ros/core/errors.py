"""The one exception type for bad user input.

Anything a user can get wrong (a file, an image, a parameter, a bag) raises
:class:`InputError` with a message that names the value and what was expected.
The CLI turns it into one line on stderr and exit code 2, without a traceback;
everything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path


class InputError(ValueError):
    """Bad user input: the message names the value and what was expected."""


def input_file(path: str | os.PathLike[str], what: str) -> Path:
    """``path`` as a Path when it is a regular file, else InputError naming ``what`` and the path.

    A missing path "does not exist"; a directory "is a directory: expected a file" (not a misleading
    "does not exist").
    """
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{what} {str(p)!r} is a directory: expected a file")
    if not p.exists():
        raise InputError(f"{what} {str(p)!r} does not exist")
    if not p.is_file():
        raise InputError(f"{what} {str(p)!r} is not a regular file: expected a file")
    return p


def output_file(path: str | os.PathLike[str], option: str, suffixes: tuple[str, ...] = ()) -> Path:
    """A file ``option`` names to write, checked before anything is created: not a directory, and no
    existing file where a directory of its path should be; with ``suffixes``, a name ending in one of them
    (case-insensitive), since the file is written in that format whatever its name says. Its parent is
    created later, by :func:`make_parent` (as every command's ``--out FILE`` does), once the rest of the
    input has been checked."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"{option} {str(p)!r} is a directory: expected a file name")
    if suffixes and p.suffix.lower() not in suffixes:
        raise InputError(f"{option} {str(p)!r}: expected a {' or '.join(suffixes)} file name (it is written in that "
                         "format)")
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise InputError(f"{option} {str(p)!r}: {str(parent)!r} is not a directory: expected a path "
                                 "under a directory")
            break
    return p


def output_dir(path: str | os.PathLike[str], option: str) -> Path:
    """A directory ``option`` names to write into: InputError when the path exists and is not a directory (it is
    created later, once the rest of the input has been checked)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{option} {str(p)!r} exists and is not a directory: expected a directory")
    return p


def make_parent(path: Path, option: str) -> None:
    """Create ``path``'s parent directories (as ``mkdir -p``), saying so when it creates one (a mistyped
    ``--out /nonexistent_dir/x.npz`` should not leave a directory behind silently); an OSError becomes one
    line naming ``option``."""
    parent = path.parent
    missing = next((p for p in reversed([parent, *parent.parents]) if not p.exists()), None)
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{option} {str(path)!r}: cannot create its directory: {exc.strerror or exc}") from None
    if missing is not None:
        print(f"created directory {str(parent)!r} for {option}")


def writable_path(path: str | os.PathLike[str], option: str) -> Path:
    """``path``, a file or directory a command is to write, checked for writing before the command works:
    InputError naming ``option`` when the path or, where it does not exist yet, the nearest directory above it
    that does cannot be written (a read-only mount, a directory without write permission).

    Checked by creating (and at once removing) a nameless file there, since permission bits do not tell: root
    passes them, and a read-only mount refuses everyone. Nothing is created at ``path`` itself.
    """
    p = Path(path)
    existing = next((q for q in [p, *p.parents] if q.exists()), Path("."))
    if existing.is_dir():
        try:
            with tempfile.TemporaryFile(dir=existing):
                pass
        except OSError as exc:
            where = "" if existing == p else f": its directory {str(existing)!r}"
            raise InputError(f"{option} {str(p)!r}{where} is not writable ({exc.strerror or exc}): expected a path "
                             "you can write") from None
    elif not os.access(existing, os.W_OK) or _read_only_mount(existing):
        where = "" if existing == p else f": {str(existing)!r} is a file"
        raise InputError(f"{option} {str(p)!r}{where} is not writable: expected a path you can write")
    return p


def _read_only_mount(path: Path) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False
