"""The public API as type checkers see it: ``lfsf/py.typed`` tells them to trust the
annotations, so the names that ``lfsf`` loads on first use must be typed as what they
are, not Any, and a wrong call must be an error (mypy, where it is installed)."""

from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

import lfsf

INIT = Path(lfsf.__file__)


def _type_checking_imports() -> tuple[dict[str, str], set[str]]:
    """The names that ``lfsf/__init__.py``'s ``if TYPE_CHECKING:`` block imports (name →
    module), and the submodules it imports."""
    tree = ast.parse(INIT.read_text(encoding="utf-8"))
    blocks = [node for node in tree.body if isinstance(node, ast.If) and isinstance(node.test, ast.Name)
              and node.test.id == "TYPE_CHECKING"]
    assert len(blocks) == 1, "lfsf/__init__.py should have one `if TYPE_CHECKING:` block"
    names: dict[str, str] = {}
    submodules: set[str] = set()
    for node in blocks[0].body:
        assert isinstance(node, ast.ImportFrom), ast.dump(node)
        for alias in node.names:
            if node.module == "lfsf":
                submodules.add(alias.name)
            else:
                # `from m import X as X`: the explicit re-export that type checkers take as public
                assert alias.asname == alias.name, f"import {alias.name} as {alias.name} (a re-export)"
                names[alias.name] = str(node.module)
    return names, submodules


def test_what_type_checkers_read_is_what_lfsf_loads_on_first_use():
    """Every lazily loaded name and submodule is imported for type checkers from the
    module that defines it (an `Any` to mypy otherwise), and ``__all__`` is a literal
    list of them (type checkers do not evaluate ``sorted(_LAZY)``)."""
    names, submodules = _type_checking_imports()
    assert names == lfsf._LAZY
    assert submodules == set(lfsf.SUBMODULES)
    tree = ast.parse(INIT.read_text(encoding="utf-8"))
    (value,) = [node.value for node in tree.body if isinstance(node, ast.Assign)
                and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)]
    literal = ast.literal_eval(value)
    assert sorted(literal) == sorted([*lfsf._LAZY, "__version__"]) and len(set(literal)) == len(literal)
    for name in names:
        assert getattr(lfsf, name) is getattr(importlib.import_module(names[name]), name)


USER_PROGRAM = '''
import numpy as np
import lfsf
from lfsf import evaluate, synth

lf1, lf2, truth = lfsf.render_scene("two_planes", size=(64, 48), grid=5)
lf = lfsf.LightField([[np.zeros((8, 8), np.float32)]], source="a list")
sf = lfsf.estimate_scene_flow(lf1, lf2, "fast", device="cpu")
errors = evaluate.evaluate(sf, truth)
mse = errors["disp1"]["mse"]
percent = 100 * errors["flow"]["epe"] + round(errors["disp1"]["mse"], 3)
f1 = errors["occluded"]["f1"]
camera = lfsf.Camera.from_truth(truth)
points1, points2 = sf.points(camera)
reveal_type(lf1)
reveal_type(sf)
reveal_type(lfsf.Params.preset("paper"))
reveal_type(synth.render_scene)
reveal_type(mse)
reveal_type(points1)
reveal_type(f1)
'''

WRONG_PROGRAM = '''
import lfsf

lf1, lf2, truth = lfsf.render_scene("two_planes", size=(64, 48))
sf = lfsf.estimate_scene_flow(lf1, lf2, device=3)
sf.nothing
'''


def test_mypy_types_the_public_api_and_refuses_a_wrong_call(tmp_path):
    """mypy --strict on a user's program: a correct one has no error, its values are
    typed (LightField, SceneFlow, Params; an error figure a float, the occlusion row's
    shares too, NaN where a share of nothing), and a wrong argument type or attribute is
    an error (with the lazily loaded names typed Any both passed)."""
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (the dev extra installs it)")
    root = INIT.parent.parent
    (tmp_path / "user.py").write_text(USER_PROGRAM, encoding="utf-8")
    (tmp_path / "wrong.py").write_text(WRONG_PROGRAM, encoding="utf-8")
    # lfsf's own modules are not this test's subject (nor Warp's kernels, which mypy cannot
    # read); an editable install is an import hook that mypy does not follow: the checkout
    config = ["[mypy]", "ignore_missing_imports = True", "[mypy-lfsf.*]", "ignore_errors = True",
              "[mypy-lfsf]", "ignore_errors = True"]
    if (root / "pyproject.toml").is_file():
        config.insert(1, f"mypy_path = {root}")
    (tmp_path / "mypy.ini").write_text("\n".join(config) + "\n", encoding="utf-8")
    out = subprocess.run([sys.executable, "-m", "mypy", "--strict", "--no-incremental", "--config-file", "mypy.ini",
                          "--cache-dir", str(tmp_path / "cache"), "user.py", "wrong.py"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=600)
    lines = out.stdout.splitlines()
    # (older mypy names builtins' types in full)
    notes = [line.split('Revealed type is "', 1)[1].rstrip('"').replace("builtins.", "") for line in lines
             if "Revealed type" in line]
    errors = [line for line in lines if ": error:" in line]
    assert [e for e in errors if e.startswith("user.py")] == [], out.stdout
    assert len(notes) == 7, out.stdout + out.stderr
    assert notes[0] == "lfsf.io.LightField" and notes[1] == "lfsf.estimate.SceneFlow", notes
    assert notes[2] == "lfsf.params.Params", notes
    assert "-> tuple[lfsf.io.LightField, lfsf.io.LightField, dict[str, Any]]" in notes[3], notes
    assert notes[4] == "float" and notes[5].startswith("numpy.ndarray"), notes
    assert notes[6] == "float", notes
    wrong = [e for e in errors if e.startswith("wrong.py")]
    assert len(wrong) == 2 and "wrong.py:5:" in wrong[0] and '"device"' in wrong[0], out.stdout
    assert "wrong.py:6:" in wrong[1] and '"nothing"' in wrong[1], out.stdout
