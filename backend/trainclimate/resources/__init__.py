"""The files the package ships beside its code: the Alembic migrations (``migrations``) and the
dashboard's static files (``frontend``), found through :mod:`importlib.resources` so that an
installed wheel (no source tree) migrates and serves the dashboard as a checkout does.

In the repository both are symbolic links to the top-level ``migrations/`` and ``frontend/``
directories; building the wheel or the sdist copies their files into the package
(``[tool.setuptools.package-data]`` of ``pyproject.toml``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def _directory(name: str) -> Path:
    """The packaged directory ``name`` as a file-system path (Alembic and Starlette's static
    files read directories; the package is installed unzipped, as pip does)."""
    path = resources.files(__name__) / name
    if not isinstance(path, Path) or not path.is_dir():
        raise FileNotFoundError(f"the package's {name}/ directory is missing ({path})")
    return path


def migrations_dir() -> Path:
    """The Alembic migrations (``env.py``, ``versions/``)."""
    return _directory("migrations")


def frontend_dir() -> Path:
    """The dashboard's static files (``index.html``, ``app.js``, …)."""
    return _directory("frontend")
