"""How lfsf is found and described once installed, or run from a source checkout."""

from __future__ import annotations

import importlib.metadata
import json
import shutil
import subprocess
import sys
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

import lfsf

ROOT = Path(lfsf.__file__).parent.parent


@pytest.mark.skipif(not (ROOT / "kernels" / "__init__.py").is_file(), reason="lfsf is not run from a source checkout")
def test_a_checkout_run_in_place_takes_its_own_kernels(tmp_path):
    """``python -m lfsf`` (or ``-m pytest``) in a checkout's root imports ``./lfsf``, whose
    kernels are ``./kernels``: not missing where lfsf is installed from a wheel, nor
    another tree's where an editable install elsewhere maps ``lfsf.kernels``. A copy of
    this checkout, imported with this interpreter (whose lfsf lives elsewhere), takes the
    copy's kernels."""
    for folder in ("lfsf", "kernels"):
        shutil.copytree(ROOT / folder, tmp_path / folder, ignore=shutil.ignore_patterns("__pycache__"))
    out = subprocess.run([sys.executable, "-c", "import lfsf, lfsf.kernels, lfsf.kernels.tgv as t; "
                          "print(lfsf.__file__); print(lfsf.kernels.__file__); print(t.__file__)"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    paths = [Path(line).resolve() for line in out.stdout.splitlines()]
    copy = tmp_path.resolve()
    assert paths == [copy / "lfsf" / "__init__.py", copy / "kernels" / "__init__.py", copy / "kernels" / "tgv.py"]


def _installed_from_here(dist) -> bool:
    """Whether the installed distribution ``dist`` is the lfsf imported here: its files hold
    this ``lfsf/__init__.py`` (a wheel), or it is an editable install of this checkout."""
    here = Path(lfsf.__file__).resolve()
    if any(Path(str(dist.locate_file(f))).resolve() == here for f in dist.files or ()):
        return True
    try:
        url = json.loads(dist.read_text("direct_url.json") or "{}").get("url", "")
    except ValueError:
        return False
    parsed = urllib.parse.urlparse(url)
    return parsed.scheme == "file" and Path(urllib.request.url2pathname(parsed.path)).resolve() == ROOT.resolve()


def test_the_installed_version_is_lfsfs_own():
    """pyproject.toml takes the version from ``lfsf.__version__`` (one place to change it):
    the installed metadata says the imported lfsf's version (where the install is this
    lfsf, not another tree's)."""
    try:
        dist = importlib.metadata.distribution("lfsf")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("lfsf is not installed (imported from a checkout)")
    if not _installed_from_here(dist):
        pytest.skip("the lfsf installed is another tree's (this one is run in place)")
    assert dist.version == lfsf.__version__
