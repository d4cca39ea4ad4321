"""The one exception type for bad user input.

Anything a user can get wrong (a file, an image, a parameter, a bag) raises
:class:`InputError` with a message that names the value and what was expected.
The CLI turns it into one line on stderr and exit code 2, without a traceback;
everything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import os
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

