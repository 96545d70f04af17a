"""The package installs anywhere: ``python -m build`` makes an sdist and a wheel (built from the
sdist), both holding the migrations and the dashboard's files inside the package; the wheel
installed into a fresh virtual environment outside the repository runs ``trainclimate serve
--fleet demo`` with a new home: it migrates, serves the dashboard and its assets, and an activated
coach gets its first DDPC setpoint.

The fresh environment is a ``python -m venv --without-pip`` whose only link to the test's
environment is a ``.pth`` file naming that environment's ``site-packages``, for the dependencies
(a line of a ``.pth`` file adds a directory to ``sys.path`` without running that directory's own
``.pth`` files, so the checkout's editable install stays out of it); the wheel is installed with
``--no-deps`` by the test environment's pip (``pip --python``; ``--ignore-installed``: the
checkout's editable install, seen through the ``.pth`` file, is neither reused nor touched).
Nothing of the repository is on the path: the test asserts the package it ran is the installed
one.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import httpx
import pytest

from helpers.processes import Server, free_port
from helpers.service import wait_for

pytestmark = pytest.mark.package
ROOT = Path(__file__).resolve().parents[2]
#: What the package must carry inside it, relative to the package (``trainclimate/``).
PACKAGED = [
    "resources/migrations/env.py",
    "resources/migrations/script.py.mako",
    "resources/migrations/versions/0001_initial_schema.py",
    "resources/frontend/index.html",
    "resources/frontend/app.js",
    "resources/frontend/style.css",
]


def build(out: Path) -> dict[str, Path]:
    """``python -m build`` of the checkout (sdist, then the wheel from it; no isolation: the
    test environment's setuptools) into ``out``: one test does it, so that two workers of
    the suite never build in the same checkout at once."""
    done = subprocess.run(
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    [wheel] = out.glob("trainclimate-*.whl")
    [sdist] = out.glob("trainclimate-*.tar.gz")
    return {"wheel": wheel, "sdist": sdist}


def check_contents(dist: dict[str, Path]) -> None:
    """The wheel and the sdist hold the migrations and the dashboard's files as files."""
    with zipfile.ZipFile(dist["wheel"]) as whl:
        names = set(whl.namelist())
    assert {f"trainclimate/{p}" for p in PACKAGED} <= names
    versions = sorted(p.name for p in (ROOT / "migrations" / "versions").glob("*.py"))
    assert versions == sorted(
        Path(n).name
        for n in names
        if n.startswith("trainclimate/resources/migrations/versions/") and n.endswith(".py")
    )
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    with tarfile.open(dist["sdist"]) as sdist:
        members = {m.name.partition("/")[2]: m for m in sdist.getmembers()}
    for path in PACKAGED:
        member = members[f"backend/trainclimate/{path}"]
        assert member.isfile(), f"{path} is a {member.type!r} in the sdist, not a file"


def fresh_venv(where: Path, wheel: Path) -> Path:
    """A new virtual environment at ``where`` with ``wheel`` installed (``--no-deps``), its
    dependencies seen through a ``.pth`` file naming this environment's ``site-packages``; its
    ``bin`` directory."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True)
    [site] = (where / "lib").glob("python3*/site-packages")
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    done = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(where / "bin" / "python"), "install",
         "--no-deps", "--no-index", "--ignore-installed", "--quiet", str(wheel)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return where / "bin"


def test_the_wheel_and_sdist_carry_the_files_and_the_wheel_serves_the_demo_elsewhere(
    tmp_path, small_predictor_file
):
    dist = build(tmp_path / "dist")
    check_contents(dist)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    bin_dir = fresh_venv(outside / "venv", dist["wheel"])
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith("TRAINCLIMATE_") and k not in ("PYTHONPATH", "VIRTUAL_ENV")
    }
    env.update(HOME=str(outside / "home-that-does-not-exist"), PYTHONUNBUFFERED="1")
    where = subprocess.run(
        [bin_dir / "python", "-c", "import trainclimate; print(trainclimate.__file__)"],
        capture_output=True, text=True, env=env, cwd=outside, check=True,
    ).stdout.strip()  # fmt: skip
    assert Path(where).is_relative_to(outside / "venv"), where
    port = free_port()
    args = [str(bin_dir / "trainclimate"), "serve", "--fleet", "demo", "--port", str(port)]
    args += ["--predictor", str(small_predictor_file), "--speedup", "600", "--new-token", "viewer"]
    server = Server(args, env, port, tmp_path / "server.log")
    server.env = env
    try:
        server.start(timeout=90)
        token = server.printed(r"viewer token: (\S+)").group(1)
        headers = {"Authorization": f"Bearer {token}"}
        page = httpx.get(f"{server.url}/", timeout=10)
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        # the files as the page names them: versioned by their content (name?v=hash)
        assets = re.findall(r'(?:src|href)="/?([\w./-]+\.(?:js|css))(\?v=\w+)?"', page.text)
        assert "app.js" in [name for name, _ in assets], assets
        for name, version in assets:
            reply = httpx.get(f"{server.url}/{name}{version}", timeout=10)
            assert reply.status_code == 200 and reply.content, name
        # the modules app.js imports, from the package
        assert httpx.get(f"{server.url}/js/api.js", timeout=10).status_code == 200
        assert httpx.get(f"{server.url}/api/v1/ready", timeout=10).status_code == 200
        coaches = httpx.get(f"{server.url}/api/v1/coaches", headers=headers, timeout=10).json()
        active = [c["id"] for c in coaches if c["ddpc_active"]]
        assert active, coaches

        def ddpc() -> bool:
            for coach in active:
                url = f"{server.url}/api/v1/coaches/{coach}/setpoints"
                reply = httpx.get(url, headers=headers, timeout=10).json()
                if "ddpc" in reply["source"]:
                    return True
            return False

        wait_for(ddpc, 90, "the first DDPC setpoint")
        home = outside / "home-that-does-not-exist"
        assert list(home.rglob("trainclimate.db")), "the database is in the new home"
    finally:
        server.stop()
    assert "Traceback" not in server.output(), server.output()
