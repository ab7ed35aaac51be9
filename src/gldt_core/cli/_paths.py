"""Output paths checked before any work is done, so a bad one costs one line instead of a run.

(A module starting with ``_`` is not a subcommand: :func:`gldt_core.cli.build_parser` skips it.)
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def check_output_path(text: str, option: str) -> Path:
    """``text`` as a path that a file can be written to (created or replaced), else a
    :class:`~gldt_core.cli.CliError` naming ``option`` and what is wrong.

    The outputs are written to a temporary name in the same folder and renamed, so what must be
    writable is the folder; a folder that does not exist yet must be creatable under its nearest
    existing parent. Writability is tried with a throw-away file, not guessed from permission bits
    (root ignores those, read-only file systems do not show in them). Nothing is left behind.
    """
    from gldt_core.cli import CliError

    path = Path(text)
    if text.endswith(("/", os.sep)) or path.is_dir():
        raise CliError(f"{option} {text}: is a folder; name the file to write")
    if path.exists() and not path.is_file():
        raise CliError(f"{option} {text}: exists and is not a regular file")
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise CliError(f"{option} {text}: {folder} is not a folder")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=f".{path.name}.", suffix=".probe"):
            pass
    except OSError as error:
        reason = error.strerror or type(error).__name__
        raise CliError(f"{option} {text}: cannot write in {folder} ({reason})") from None
    return path


def remove_quietly(*paths: Path) -> None:
    """Delete leftover temporary files, ignoring the ones that are not there."""
    for path in paths:
        try:
            path.unlink()
        except OSError:
            pass
