"""scripts/sweep.py: copies of each scene with imperceptible noise, to tell a setting's
effect from the chance of the estimator's hard choices."""

import json
import math

import numpy as np
import pytest

from lfsf import synth
from lfsf.io import LightField

from conftest import load_script


def _sweep_script():
    return load_script("sweep")


def test_copies_are_the_rendering_then_reproducible_independent_noise():
    sweep = _sweep_script()
    rng = np.random.default_rng(0)
    views = rng.uniform(0.2, 0.8, (3, 3, 40, 50)).astype(np.float32)
    lf1, lf2 = LightField(views), LightField(views.copy())
    a, b = sweep.perturbed(lf1, lf2, 0.01, 0, "paper")
    assert a is lf1 and b is lf2  # copy 0: the rendering itself
    a1, b1 = sweep.perturbed(lf1, lf2, 0.01, 1, "paper")
    n1, m1 = a1.views - views, b1.views - views
    assert np.std(n1) == pytest.approx(0.01, rel=0.05) and np.std(m1) == pytest.approx(0.01, rel=0.05)
    assert abs(np.corrcoef(n1.ravel(), m1.ravel())[0, 1]) < 0.05  # t1 and t2 independent
    again = sweep.perturbed(lf1, lf2, 0.01, 1, "paper")
    assert np.array_equal(again[0].views, a1.views) and np.array_equal(again[1].views, b1.views)
    a2, _ = sweep.perturbed(lf1, lf2, 0.01, 2, "paper")
    other, _ = sweep.perturbed(lf1, lf2, 0.01, 1, "slanted")
    assert abs(np.corrcoef(n1.ravel(), (a2.views - views).ravel())[0, 1]) < 0.05
    assert abs(np.corrcoef(m1.ravel(), (a2.views - views).ravel())[0, 1]) < 0.05  # no seed shared across copies
    assert abs(np.corrcoef(n1.ravel(), (other.views - views).ravel())[0, 1]) < 0.05


def test_summary_gives_the_geometric_means_and_their_range_over_the_copies():
    sweep = _sweep_script()
    rows = {"a": [{"disp1": 1.0, "disp2": 2.0, "epe": 4.0}, {"disp1": 4.0, "disp2": 2.0, "epe": 1.0}],
            "b": [{"disp1": 1.0, "disp2": 8.0, "epe": 4.0}, {"disp1": 1.0, "disp2": 2.0, "epe": 1.0}]}
    g, spread = sweep.summary(rows)
    assert g["disp1"] == pytest.approx(4.0 ** 0.25) and g["disp2"] == pytest.approx(math.sqrt(8.0))
    assert g["epe"] == pytest.approx(2.0)
    assert spread["disp1"] == pytest.approx((1.0, 2.0))  # copy 0: gmean(1, 1); copy 1: gmean(4, 1)
    assert spread["disp2"] == pytest.approx((2.0, 4.0))
    assert spread["epe"] == pytest.approx((1.0, 4.0))


def test_a_sweep_with_copies_keeps_the_rendering_as_its_first(tmp_path, capsys):
    """Copy 0 of a run with copies is the run without them, to the last digit; the
    others differ, and the table gives the range."""
    sweep = _sweep_script()
    common = ["--size", "32", "24", "--preset", "fast", "--scenes", "paper", "--device", "cpu"]
    assert sweep.main([*common, "--json", str(tmp_path / "one.json")]) == 0
    capsys.readouterr()
    assert sweep.main([*common, "--seeds", "3", "--perturb", "0.02", "--json", str(tmp_path / "three.json")]) == 0
    table = capsys.readouterr().out
    assert "range over copies" in table
    cells = next(line for line in table.splitlines() if line.startswith("| base |")).split("|")[2]
    one = json.loads((tmp_path / "one.json").read_text())["results"][0]
    three = json.loads((tmp_path / "three.json").read_text())
    assert three["seeds"] == 3 and three["perturb"] == 0.02
    result = three["results"][0]
    copies = result["copies"]["paper"]
    assert len(copies) == 3
    assert result["scenes"]["paper"] == copies[0]
    # the table's cell: each error's median over the copies
    shown = [float(v) for v in cells.split("/")[:3]]
    for k, v in zip(("disp1", "disp2", "epe"), shown):
        median = float(np.median([c[k] for c in copies]))
        assert result["median"]["paper"][k] == median
        assert v == pytest.approx(median, abs=0.000051 if k != "epe" else 0.00051)
    for k in ("disp1", "disp2", "epe"):
        assert copies[0][k] == one["scenes"]["paper"][k]
        low, high = result["geomean_range"][k]
        assert low <= min(c[k] for c in copies) * (1 + 1e-9) and high >= max(c[k] for c in copies) * (1 - 1e-9)
    assert any(copies[1][k] != copies[0][k] for k in ("disp1", "disp2", "epe"))



def test_a_sweep_puts_the_photographs_on_the_objects(tmp_path, capsys, monkeypatch):
    """--images FOLDER: the scene keeps its geometry and shows the folder's images, each
    object's drawn from the scene's name as compare_peers.py --images draws them; the
    result differs from the solid texture's. A missing folder is named."""
    import zlib

    import imageio.v3 as iio

    rng = np.random.default_rng(2)
    for k in range(2):
        iio.imwrite(tmp_path / f"p{k}.png", (rng.random((40, 60, 3)) * 255).astype(np.uint8))
    sweep = _sweep_script()
    rendered = []
    render = synth.render_scene

    def recording(scene, **kwargs):
        rendered.append((scene, kwargs.get("images")))
        return render(scene, **kwargs)

    monkeypatch.setattr(synth, "render_scene", recording)
    common = ["--size", "32", "24", "--preset", "fast", "--scenes", "slanted", "--device", "cpu"]
    assert sweep.main([*common, "--json", str(tmp_path / "solid.json")]) == 0
    assert sweep.main([*common, "--images", str(tmp_path), "--json", str(tmp_path / "photo.json")]) == 0
    assert f"photographs from {tmp_path}" in capsys.readouterr().out
    assert rendered[0] == ("slanted", None)
    scene, images = rendered[1]
    assert len(images) == 2
    assert scene == synth.with_images("slanted", 2, seed=zlib.crc32(b"slanted"))
    assert all(obj.texture.image >= 0 for obj in scene.objects)
    solid = json.loads((tmp_path / "solid.json").read_text())
    photo = json.loads((tmp_path / "photo.json").read_text())
    assert solid["images"] is None and photo["images"] == str(tmp_path)
    assert photo["results"][0]["scenes"]["slanted"] != solid["results"][0]["scenes"]["slanted"]
    with pytest.raises(FileNotFoundError, match="no such folder"):
        sweep.main([*common, "--images", str(tmp_path / "missing")])


def test_photographs_from_scikit_image_are_its_samples():
    pytest.importorskip("skimage")
    images = synth.photographs("skimage")
    assert len(images) == len(synth.SKIMAGE_IMAGES) == 10
    assert all(np.asarray(a).ndim in (2, 3) and min(np.shape(a)[:2]) >= 256 for a in images)
