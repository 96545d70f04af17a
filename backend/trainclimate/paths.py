"""Where trainclimate writes, and making sure it can.

Every place the product writes — its home (``$TRAINCLIMATE_HOME``, default
``~/.cache/trainclimate``) with the default dataset, the model store and the embedded SQLite
database, and every ``--out`` or report file a command is given — is created with its parents
before the first write. Where that cannot be done (a file in the way, a read-only directory) a
:class:`StorageError` says so in one line, naming the path and what to do.
"""

from __future__ import annotations

import os
from pathlib import Path

#: What to do when the product's own home cannot be written.
HOME_HINT = "set TRAINCLIMATE_HOME or TRAINCLIMATE_DATABASE_URL to a writable place"


class StorageError(OSError):
    """A place trainclimate must write to cannot be created or written (one-line message)."""


def home() -> Path:
    """The directory trainclimate keeps built data, models and its SQLite database in.

    Returns
    -------
    pathlib.Path
        ``$TRAINCLIMATE_HOME``, else ``~/.cache/trainclimate`` (not created here: see
        :func:`writable_dir`).
    """
    return Path(os.environ.get("TRAINCLIMATE_HOME") or Path.home() / ".cache" / "trainclimate")


def writable_dir(path: str | Path, what: str, hint: str = HOME_HINT) -> Path:
    """Create directory ``path`` with its parents if missing and check it can be written.

    Parameters
    ----------
    path : str or pathlib.Path
        The directory.
    what : str
        What goes there, for the message (``"the model store"``).
    hint : str
        What the user can do about it, for the message.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    StorageError
        A file is in the way, or the directory cannot be created or written.
    """
    path = Path(path).expanduser()
    blocker = next((p for p in (path, *path.parents) if p.exists() and not p.is_dir()), None)
    if blocker is not None:
        reason = f"a file is in the way ({blocker})"
        raise StorageError(f"cannot create {what} at {path}: {reason}; {hint}")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise StorageError(f"cannot create {what} at {path}: {reason}; {hint}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise StorageError(f"cannot write {what} in {path}: permission denied; {hint}")
    return path


def writable_file(path: str | Path, what: str, hint: str = HOME_HINT) -> Path:
    """Make sure file ``path`` can be written: its directory is created with its parents.

    The arguments and the result are those of :func:`writable_dir`, for a file; raises
    :class:`StorageError` also when a directory stands where the file should be.
    """
    path = Path(path).expanduser()
    if path.is_dir():
        raise StorageError(f"cannot write {what} to {path}: it is a directory; {hint}")
    writable_dir(path.parent, f"the directory of {what}", hint)
    if path.exists() and not os.access(path, os.W_OK):
        raise StorageError(f"cannot write {what} to {path}: permission denied; {hint}")
    return path


def sqlite_file(url: str) -> Path | None:
    """The file of a SQLite URL (``sqlite:///path``), or None (in memory, or not SQLite)."""
    if not url.startswith("sqlite"):
        return None
    path = url.split("///", 1)[-1] if "///" in url else ""
    path = path.split("?", 1)[0]
    return Path(path) if path and path != ":memory:" else None
