"""The check that t2 shows what t1 shows (lfsf.pairing): unrelated scenes are told, a
pair of one scene (moved, re-exposed, noisy) is not."""

import warnings

import numpy as np
import pytest

import lfsf
from lfsf.pairing import PAIR_MISMATCH, mismatch, mismatch_warning
from lfsf.synth import add_noise, render_scene


def _texture(seed, shape=(72, 96)):
    rng = np.random.default_rng(seed)
    coarse = rng.random((shape[0] // 6 + 1, shape[1] // 6 + 1))
    return np.kron(coarse, np.ones((6, 6)))[:shape[0], :shape[1]]


def test_mismatch_of_known_pairs():
    image = _texture(1)
    zero = np.zeros_like(image)
    assert mismatch(image, image, zero, zero) == 0.0
    # another exposure and offset: undone by the standardisation
    assert mismatch(image, 1.4 * image + 0.1, zero, zero) == pytest.approx(0.0, abs=1e-9)
    # t2 moved 5 px right and 3 down: matched by the flow that says so, not by none
    moved = np.roll(image, (3, 5), axis=(0, 1))
    assert mismatch(image, moved, zero + 5, zero + 3) == pytest.approx(0.0, abs=1e-9)
    assert mismatch(image, moved, zero, zero) > PAIR_MISMATCH
    # an unrelated image of the same kind: about 1
    assert 0.7 < mismatch(image, _texture(2), zero, zero) < 1.3
    # too small to tell, or flat
    assert mismatch(image[:40], image[:40], zero[:40], zero[:40]) is None
    assert mismatch(zero, image, zero, zero) is None
    said = mismatch_warning(image, _texture(2), zero, zero, ("a.npz", "b.npz"), 24.0)
    assert said.startswith("b.npz does not match a.npz after the estimated flow (mismatch ")
    assert mismatch_warning(image, image, zero, zero, ("a.npz", "b.npz"), 24.0) is None


def _laid_out(caught):
    return [str(w.message) for w in caught if "does not match" in str(w.message)]


def test_estimate_warns_of_unrelated_scenes_only():
    """`random-3` at t1 with `paper` at t2 is told (once: not by the pilots), naming both;
    each scene's own pair, with noise of σ = 0.02 and t2 1.3× as bright, is not."""
    params = lfsf.Params.preset("fast")
    one, two, _ = render_scene("random-3", size=(96, 72))
    other = render_scene("paper", size=(96, 72))[1]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lfsf.estimate_scene_flow(lfsf.LightField(one.views, source="t1.npz"),
                                 lfsf.LightField(other.views, source="t2.npz"), params)
    said = _laid_out(caught)
    assert len(said) == 1 and said[0].startswith("t2.npz does not match t1.npz")
    brighter = lfsf.LightField(np.clip(add_noise(two, 0.02, 2).views * 1.3, 0, 1))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lfsf.estimate_scene_flow(add_noise(one, 0.02, 1), brighter, params)
        lfsf.estimate_scene_flow(one, two, "flow")
    assert not _laid_out(caught)
