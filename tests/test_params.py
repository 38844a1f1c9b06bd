"""Params: bad settings end in a ValueError naming the setting; good ones keep their types."""

import dataclasses
import math
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from lfsf import Params
from lfsf.params import PRESETS

INT_FIELDS = [f.name for f in dataclasses.fields(Params) if f.type == "int"]
FLOAT_FIELDS = [f.name for f in dataclasses.fields(Params) if f.type == "float"]
BOOL_FIELDS = [f.name for f in dataclasses.fields(Params) if f.type == "bool"]
OPTIONAL_FLOAT_FIELDS = [f.name for f in dataclasses.fields(Params) if f.type == "float | None"]


def named(name):
    """A pattern matching the setting's name as a word (``iterations``, not ``rof_iterations``)."""
    return rf"(?<![\w]){re.escape(name)}(?![\w])"


def assert_types(params):
    for name in INT_FIELDS:
        assert type(getattr(params, name)) is int, name
    for name in FLOAT_FIELDS:
        assert type(getattr(params, name)) is float, name
    for name in BOOL_FIELDS:
        assert type(getattr(params, name)) is bool, name
    for name in OPTIONAL_FLOAT_FIELDS:
        assert getattr(params, name) is None or type(getattr(params, name)) is float, name
    assert type(params.samples) is tuple and all(type(n) is int for n in params.samples)


def test_the_field_lists_cover_every_setting():
    assert (len(INT_FIELDS) + len(FLOAT_FIELDS) + len(BOOL_FIELDS) + len(OPTIONAL_FLOAT_FIELDS) + 1
            == len(dataclasses.fields(Params)))
    assert OPTIONAL_FLOAT_FIELDS == ["alpha0_flow"]
    assert {"warps", "iterations", "circles", "median_radius", "search_radius"} <= set(INT_FIELDS)
    assert {"visibility", "flow_search", "disparity_search", "warp_tensor2"} <= set(BOOL_FIELDS)


@pytest.mark.parametrize("name", list(PRESETS))
def test_defaults_and_presets_validate_with_their_types(name):
    params = Params.preset(name)
    params.validate()
    assert_types(params)
    assert_types(Params())
    assert Params.preset("paper") == Params()


BAD = [
    # int settings: fractions, bools, strings
    ("warps", 1.5), ("warps", True), ("warps", "3"), ("iterations", 2.5), ("iterations", "100"),
    ("circles", 1.5), ("rof_iterations", 0.5), ("median_radius", 1.5), ("search_radius", 1.5),
    ("occlusion_reach", math.inf), ("min_size", math.nan), ("max_levels", None),
    # switches: strings and numbers are not true/false
    ("visibility", "false"), ("flow_search", "false"), ("disparity_search", 1), ("warp_tensor2", None),
    ("visibility", 0),
    # samples: a list of whole numbers
    ("samples", "188"), ("samples", [1, 8.7, 8]), ("samples", 8), ("samples", None), ("samples", (1, "8", 8)),
    ("samples", [1, True, 8]),
    # float settings: real, finite, not bool
    ("lambda3", "x"), ("lambda1", True), ("radius", None), ("hidden_fill_sigma", math.inf),
    ("radius", math.nan), ("gamma", -math.inf), ("step_ratio", math.inf), ("flow_edge_weight", math.inf),
    ("occlusion_margin", math.inf), ("hidden_fill_depth", math.inf), ("lambda2", 10 ** 400),
    ("lambda3_side", -0.5), ("lambda3_side", math.nan),
    # ranges
    ("eps", 0), ("eps", 0.0), ("eps", -1e-6),
    ("colour_median_radius", 4), ("colour_median_radius", -1), ("colour_median_radius", 2.5),
    ("depth_change_radius", 4), ("depth_change_radius", -1),
    ("colour_median_separation", -0.5), ("colour_median_separation", math.nan),
    ("speckle_radius", 4), ("speckle_radius", -1), ("speckle_radius", 1.5),
    # bounds on what sizes buffers and loops
    ("occlusion_reach", 1000), ("flow_range", 1e6), ("disparity_range", 1e6), ("hidden_fill_sigma", 1000.0),
    ("flow_range_share", 0.3), ("flow_range_share", -0.01), ("flow_range_share", math.nan),
    ("iterations", 10 ** 9), ("rof_iterations", 10 ** 9), ("warps", 10 ** 6), ("samples", (1, 8, 10_000)),
    ("final_iterations", 10 ** 9), ("final_iterations", -1), ("final_iterations", 2.5),
    ("view_gain_sigma", -1.0), ("view_gain_sigma", 1000.0), ("view_gain_sigma", math.inf), ("view_gain_sigma", True),
    # side samples with no parallax to speak of (R = 1e-9 gave δ = 0 without a word)
    ("radius", 1e-9), ("radius", 0.4),
    # an open bound: at 1 every side would be "much worse" than itself
    ("occlusion_ratio", 1.0), ("occlusion_ratio", -0.1),
]


@pytest.mark.parametrize("name, value", BAD)
def test_a_bad_setting_raises_a_value_error_naming_it(name, value):
    with pytest.raises(ValueError, match=named(name)):
        Params(**{name: value})
    with pytest.raises(ValueError, match=named(name)):
        Params.preset("fast").replace(**{name: value})


@pytest.mark.parametrize("name", [n for n in INT_FIELDS if n != "circles"])
def test_whole_number_floats_are_stored_as_ints(name):
    default = getattr(Params(), name)
    value = default - 1 if default > 0 else default + 1  # a default may be its field's maximum
    params = Params(**{name: float(value)})
    assert getattr(params, name) == value and type(getattr(params, name)) is int
    assert params == Params(**{name: value})


def test_samples_are_stored_as_a_tuple_of_ints():
    params = Params.preset("fast").replace(circles=2.0, samples=[1.0, np.int64(12)])
    assert params.circles == 2 and type(params.circles) is int
    assert params.samples == (1, 12) and all(type(n) is int for n in params.samples)
    assert Params(samples=np.array([1, 8, 8])).samples == (1, 8, 8)


def test_ints_and_numpy_numbers_are_stored_as_floats_and_numpy_bools_as_bools():
    params = Params(lambda3=20, radius=np.float32(2.5), visibility=np.bool_(False))
    assert params.lambda3 == 20.0 and type(params.lambda3) is float
    assert params.radius == 2.5 and type(params.radius) is float
    assert params.visibility is False


def test_the_bounds_themselves_are_accepted():
    params = Params(disparity_range=32, flow_range=512, occlusion_reach=32, hidden_fill_sigma=64,
                    samples=(1, 127, 128), iterations=100_000, rof_iterations=100_000, warps=1000,
                    flow_range_share=0.25)
    assert params.disparity_range == 32.0 and params.samples == (1, 127, 128)
    with pytest.raises(ValueError, match="samples"):
        Params(samples=(1, 128, 128))


def test_eps_must_be_positive():
    with pytest.raises(ValueError, match=named("eps")):
        Params(eps=0)
    assert Params(eps=1e-12).eps == 1e-12


@pytest.mark.parametrize("name", [[], None, 3, "slow"])
def test_an_unknown_or_unhashable_preset_name_raises_a_value_error(name):
    with pytest.raises(ValueError, match="unknown preset"):
        Params.preset(name)


@pytest.mark.parametrize("changes", [{"iterations": "100"}, {"samples": 8}])
def test_replace_with_a_bad_type_raises_a_value_error(changes):
    with pytest.raises(ValueError, match=named(next(iter(changes)))):
        Params.preset("fast").replace(**changes)


def test_a_toml_file_with_whole_number_floats_loads(tmp_path):
    path = tmp_path / "run.toml"
    path.write_text("warps = 3.0\niterations = 40.0\nlambda3 = 20\nsamples = [1, 8.0, 8]\nvisibility = false\n")
    params = Params.from_toml(path)
    assert params.warps == 3 and type(params.warps) is int
    assert params.iterations == 40 and type(params.iterations) is int
    assert params.lambda3 == 20.0 and type(params.lambda3) is float
    assert params.samples == (1, 8, 8) and params.visibility is False


def test_a_named_pipe_is_read_as_the_config_and_a_device_without_end_is_not(tmp_path):
    """/dev/zero as the config had been read for ever; a named pipe (a shell's
    ``--config <(…)``) is read as a file."""
    import threading

    (tmp_path / "zero.toml").symlink_to("/dev/zero")
    with pytest.raises(ValueError, match="zero.toml: more than 16 MB, too long for a TOML file of settings"):
        Params.from_toml(tmp_path / "zero.toml")
    os.mkfifo(tmp_path / "fifo.toml")
    writer = threading.Thread(target=(tmp_path / "fifo.toml").write_text, args=("warps = 3\n",), daemon=True)
    writer.start()
    assert Params.from_toml(tmp_path / "fifo.toml").warps == 3
    writer.join(timeout=30)


def test_many_unknown_settings_are_named_in_a_short_message():
    """A file of 200 000 unknown names had been a message of 1.7 MB after 14 s."""
    with pytest.raises(ValueError) as info:
        Params.preset("fast").replace(**{f"k{i}": 1 for i in range(20000)})
    assert "and 19992 more" in str(info.value) and len(str(info.value)) < 1200


def test_a_toml_file_is_read_as_utf_8_whatever_the_locale(tmp_path):
    """TOML is UTF-8: a comment with δ (or Notepad's BOM) had been decoded with the
    locale's encoding, cp1252 on Windows, ASCII under LANG=C ("not valid TOML")."""
    path = tmp_path / "run.toml"
    path.write_bytes("\ufeff# δ1 smoothness, µ – “a note”\nwarps = 3\n".encode("utf-8"))
    env = {**os.environ, "PYTHONUTF8": "0", "LANG": "C", "LC_ALL": "C", "PYTHONIOENCODING": "ascii"}
    code = f"from lfsf import Params; print(Params.from_toml({str(path)!r}).warps)"
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "3", done.stderr


@pytest.mark.parametrize("text, name", [('visibility = "false"\n', "visibility"), ("warps = 1.5\n", "warps"),
                                        ('samples = "188"\n', "samples"), ("eps = 0\n", "eps"),
                                        ("flow_range = inf\n", "flow_range"), ('preset = "slow"\n', "preset"),
                                        ("preset = 3\n", "preset"), ('preset = ["fast"]\n', "preset")])
def test_a_bad_toml_setting_names_the_file_and_the_setting(tmp_path, text, name):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=named(name)) as info:
        Params.from_toml(path)
    assert str(info.value).startswith(f"{path}: ")


def test_toml_nested_too_deeply_to_read_names_the_file(tmp_path):
    """tomllib recurses once per level: 5000 nested arrays had been a RecursionError's
    traceback (a fuzzing helper)."""
    path = tmp_path / "deep.toml"
    path.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ValueError, match=re.escape(f"{path}: not valid TOML of settings (nested too deeply")):
        Params.from_toml(path)


def test_a_params_key_that_is_no_table_names_the_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("params = 3\n")
    with pytest.raises(ValueError, match=re.escape(str(path))):
        Params.from_toml(path)


def test_settings_both_in_a_params_table_and_at_the_top_level_are_an_error(tmp_path):
    """Not silently dropped: with a [params] table, `warps = 9` above it was ignored."""
    path = tmp_path / "mixed.toml"
    path.write_text('warps = 9\npreset = "fast"\n[params]\niterations = 40\n')
    with pytest.raises(ValueError, match=re.escape(f"{path}: settings both in [params] and at the top level "
                                                   "(warps)")):
        Params.from_toml(path)
    path.write_text('[params]\npreset = "fast"\nwarps = 9\n')
    assert Params.from_toml(path) == Params.preset("fast").replace(warps=9)
    # the preset at the top level, the settings in [params] (it had been called a setting
    # at the top level), and a stray table named as one
    path.write_text('preset = "fast"\n[params]\nwarps = 9\n')
    assert Params.from_toml(path) == Params.preset("fast").replace(warps=9)
    path.write_text('preset = "fast"\n[params]\npreset = "flow"\n')
    with pytest.raises(ValueError, match="preset = 'fast' at the top level but 'flow' in \\[params\\]"):
        Params.from_toml(path)
    path.write_text('[params]\nwarps = 9\n[extra]\nfoo = 1\n')
    with pytest.raises(ValueError, match=re.escape("unknown table [extra]")):
        Params.from_toml(path)
    # typos: the table's name (its settings had been read as one named "param"), a
    # setting's, the preset's, also beside --preset (it had read as a conflict)
    path.write_text('[param]\nwarps = 9\n')
    with pytest.raises(ValueError, match=re.escape(f"{path}: unknown table [param]; the settings go in [params]")):
        Params.from_toml(path)
    path.write_text('lamda3 = 2\nwarp = 3\nzzz = 1\n')
    with pytest.raises(ValueError, match=re.escape(f"{path}: unknown parameter(s) lamda3, warp, zzz (lamda3: did you "
                                                   "mean lambda3?; warp: did you mean warps?); known: circles")):
        Params.from_toml(path)
    path.write_text('lambda = 2\n')  # (every unknown name has a near one: the 50-odd names are left out)
    with pytest.raises(ValueError, match=re.escape(f"{path}: unknown parameter(s) lambda (lambda: did you mean "
                                                   "lambda1 or lambda2 or lambda3?)") + "$"):
        Params.from_toml(path)
    path.write_text('preset = "fats"\n')
    for given in (None, "fast", "paper"):
        with pytest.raises(ValueError, match=re.escape(f"{path}: unknown preset 'fats' (did you mean 'fast'?): "
                                                       "the presets are paper, fast")):
            Params.from_toml(path, preset=given)


def test_a_results_recorded_settings_serve_as_the_config(tmp_path):
    """A result (its folder or sceneflow.npz) gives back the settings it was estimated
    with: --config on it had failed as 'not valid TOML'."""
    from lfsf.estimate import SceneFlow

    params = Params.preset("fast").replace(lambda3=7.5, warps=2)
    zeros = np.zeros((8, 8), np.float32)
    SceneFlow(zeros, zeros, zeros, zeros, params=params, radius=2.0, device="cpu").save(tmp_path / "r")
    assert Params.from_toml(tmp_path / "r") == params
    assert Params.from_toml(tmp_path / "r" / "sceneflow.npz") == params
    with pytest.raises(ValueError, match="recorded settings are complete; --preset fast"):
        Params.from_toml(tmp_path / "r", preset="fast")
    np.savez(tmp_path / "other.npz", views=zeros)
    with pytest.raises(ValueError, match="records no settings of lfsf"):
        Params.from_toml(tmp_path / "other.npz")


def test_alpha0_flow_follows_alpha0_unless_given_and_old_results_keep_one_alpha0(tmp_path):
    """``alpha0_flow`` None (the default) is α0: a TOML file or a call setting alpha0
    alone sets the flow's too, as before the setting existed; and a sceneflow.npz written
    before it (no alpha0_flow recorded), estimated with α0 on the flow, reads back (as
    --config and by SceneFlow.load) so."""
    import json

    from lfsf.estimate import SceneFlow

    assert Params().replace(alpha0=3.0).flow_alpha0 == 3.0
    assert Params().replace(alpha0=3.0, alpha0_flow=1.5).flow_alpha0 == 1.5
    with pytest.raises(ValueError, match="alpha0_flow must be positive"):
        Params(alpha0_flow=0.0)
    params = Params.preset("fast").replace(alpha0=4.5, alpha0_flow=1.0)
    zeros = np.zeros((8, 8), np.float32)
    SceneFlow(zeros, zeros, zeros, zeros, params=params, radius=2.0, device="cpu").save(tmp_path / "r")
    file = tmp_path / "r" / "sceneflow.npz"
    with np.load(file) as f:
        arrays = dict(f)
    meta = json.loads(str(arrays["params"]))
    del meta["params"]["alpha0_flow"]
    arrays["params"] = np.array(json.dumps(meta))
    np.savez(file, **arrays)
    assert Params.from_toml(tmp_path / "r") == params.replace(alpha0_flow=None)
    assert SceneFlow.load(file).params.flow_alpha0 == 4.5


def test_a_folder_given_as_the_config_is_a_value_error(tmp_path):
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path}: a folder, not a TOML file")):
        Params.from_toml(tmp_path)


def test_a_preset_named_both_on_the_command_line_and_in_the_file_must_agree(tmp_path):
    """`--preset paper --config f.toml` with `preset = "flow"` in the file ran the flow
    preset (δ1 all zero) without a word."""
    path = tmp_path / "f.toml"
    path.write_text('preset = "flow"\nwarps = 2\n')
    with pytest.raises(ValueError, match=re.escape(f"{path}: preset = 'flow' here, but preset 'paper' was given")):
        Params.from_toml(path, preset="paper")
    assert Params.from_toml(path, preset="flow") == Params.preset("flow").replace(warps=2)
    assert Params.from_toml(path) == Params.preset("flow").replace(warps=2)
    path.write_text("warps = 2\n")
    assert Params.from_toml(path, preset="fast") == Params.preset("fast").replace(warps=2)


@pytest.mark.parametrize("name, value", [("lambda1", 1e39), ("alpha0", 1e308), ("step_ratio", 1e-308),
                                         ("contrast", 1e308), ("flow_edge_weight", 1e12)])
def test_real_settings_beyond_what_float32_kernels_can_carry_are_refused(name, value):
    """Each was accepted and made every map NaN (λ = 1e39 is past float32's 3.4e38)."""
    # (a setting that must be positive is not told it may be 0: eps = 0 is refused)
    may_be_zero = name not in ("alpha0", "step_ratio")
    with pytest.raises(ValueError, match=named(name) + (r".*must be 0 or of magnitude" if may_be_zero else
                                                        r".*must be positive and of magnitude") + r" 1e-12…1e\+09"):
        Params.preset("fast").replace(**{name: value})
    Params.preset("fast").replace(**{name: 1e9 if value > 1 else 1e-12})
    if not may_be_zero:
        with pytest.raises(ValueError, match="positive"):
            Params.preset("fast").replace(**{name: 0.0})


def test_sample_offsets_take_a_square_grid_as_one_number():
    params = Params.preset("paper")
    for a, b in zip(params.sample_offsets(9), params.sample_offsets((9, 9))):
        np.testing.assert_array_equal(a, b)


def test_the_presets_hold_the_settings_the_readme_and_the_issue_name():
    """The presets are documented settings (README's presets paragraph; issue 3: the
    paper's synthetic M = 3, N = (1, 8, 8), R = 4, and its Lytro M = 2, N = (1, 16)), not
    tuning knobs the accuracy tests would notice: `fast`'s warps 3 → 2 costs the slanted
    scene's flow 1.6× at 96×72, inside the loose end-to-end guards."""
    paper = Params.preset("paper")
    assert (paper.circles, paper.samples, paper.radius) == (3, (1, 8, 8), 4.0)
    assert len(paper.sample_offsets((9, 9))[0]) == 17
    fast = Params.preset("fast")
    assert len(fast.sample_offsets((9, 9))[0]) == 9  # "9 views"
    assert (fast.warps, fast.iterations, fast.final_iterations, fast.view_gain_sigma) == (3, 30, 0, 24.0)
    lytro = Params.preset("lytro")
    assert (lytro.circles, lytro.samples) == (2, (1, 16))
    flow = Params.preset("flow")
    assert (flow.circles, flow.samples, flow.warps, flow.iterations, flow.step_ratio) == (1, (1,), 5, 20, 0.25)
    # a preset differs from the defaults only in what it names
    for name, settings in PRESETS.items():
        differing = {f for f in Params.__dataclass_fields__ if getattr(Params.preset(name), f) != getattr(Params(), f)}
        assert differing <= set(settings), (name, differing - set(settings))


def test_the_least_radius_is_accepted_and_flow_only_needs_none():
    from lfsf.params import MIN_RADIUS

    assert Params(radius=MIN_RADIUS).radius == MIN_RADIUS
    assert Params(circles=1, samples=(1,), radius=1e-9).circles == 1


def test_flow_only_is_one_circle_and_no_setting():
    """``Params.flow_only`` (M = 1), what the scoring, the pictures and ``run --gt`` ask,
    is derived, not a setting of its own."""
    assert Params.preset("flow").flow_only and Params(circles=1, samples=(1,)).flow_only
    assert not Params().flow_only and not Params.preset("fast").flow_only
    assert "flow_only" not in Params().as_dict()
    with pytest.raises(ValueError, match="unknown parameter"):
        Params().replace(flow_only=True)


def test_repr_names_only_the_settings_that_differ_and_makes_them_again():
    """All 60 settings made a repr of 900 characters; now those that differ from the
    defaults (the `paper` preset), as a call that gives the same Params."""
    from lfsf.params import PRESETS

    assert repr(Params()) == "Params()"
    assert repr(Params().replace(lambda3=31.0, samples=(1, 6, 6))) == "Params(samples=(1, 6, 6), lambda3=31.0)"
    for name in PRESETS:
        params = Params.preset(name)
        assert eval(repr(params), {"Params": Params}) == params, name


@pytest.mark.parametrize("radius, circles, samples, inner", [
    (4.0, 3, (1, 8, 8), [2.0]),            # the paper's: already whole
    (3.0, 3, (1, 8, 8), [2.0]),            # 1.5 → 2 (halves up)
    (2.5, 3, (1, 8, 8), [1.0]),            # 1.25 → 1
    (4.0, 4, (1, 8, 8, 8), [1.0, 3.0]),    # 4/3, 8/3 → 1, 3
    (1.5, 3, (1, 8, 8), [1.0]),            # 0.75 → 1
    (1.0, 3, (1, 8, 8), [0.5]),            # 1 would not be below R: kept
    (0.8, 3, (1, 8, 8), [0.4]),            # 0 would be the centre: kept
    (2.0, 5, (1, 8, 8, 8, 8), [0.5, 1.0, 1.5]),  # 0.5 → 1 and 1.5 → 2 would meet the next circle: kept
    (5.0, 5, (1, 8, 8, 8, 8), [1.0, 3.0, 4.0]),  # 1.25, 2.5, 3.75 → 1, 3, 4
])
def test_whole_circles_put_the_inner_circles_on_whole_view_steps(radius, circles, samples, inner):
    """A sample between two views blends them (two copies of the scene δ px apart): at
    R = 3 the paper's r_1 = 1.5 had given HCI antinous a BadPix of 27.6 % against 13 % on
    whole steps (``whole_circles``). The outer circle keeps R; an inner radius moves only
    to a whole step of at least 1 and below R."""
    params = Params.preset("paper").replace(radius=radius, circles=circles, samples=samples, whole_circles=True)
    phis, used = params.sample_offsets((15, 15))
    plain = params.replace(whole_circles=False).sample_offsets((15, 15))[0]   # the paper's r_i = R·i/(M − 1)
    np.testing.assert_allclose(np.hypot(*plain[1:1 + samples[1]].T), radius / (circles - 1), rtol=1e-6)
    assert used == radius
    norms = np.hypot(phis[:, 0], phis[:, 1])
    start = 1
    for n, r in zip(samples[1:], [*inner, radius]):
        np.testing.assert_allclose(norms[start:start + n], r, rtol=1e-6)
        start += n


@pytest.mark.parametrize("grid, radius", [((1, 9), 4.0), ((9, 1), 4.0), ((2, 9), 4.0), ((3, 7), 3.0), ((7, 3), 3.0)])
def test_samples_along_the_long_axis_of_a_rig(grid, radius):
    """circles = 2, samples = [1, 2]: the two samples lie along the grid's longer axis
    (across a 1×9 rig's columns, down a 9×1 rig's rows), R as far as that axis allows
    (the grid's half extents taken per axis: swapped, a 1×9 rig had R = 0)."""
    phis, r = Params(circles=2, samples=(1, 2)).sample_offsets(grid)
    assert r == radius
    rows, cols = grid
    along = 0 if cols >= rows else 1  # (φ = (ξ along the columns, η along the rows))
    np.testing.assert_allclose(np.abs(phis[1:, along]), radius, atol=1e-6)
    np.testing.assert_allclose(phis[1:, 1 - along], 0.0, atol=1e-6)


def test_a_result_written_before_a_setting_was_added_reads_as_what_it_did(tmp_path):
    """A result recorded before flow_range_share searched ±flow_range at any size: read
    back (SceneFlow.load, --config RESULT, lfsf batch's test of a finished pair) it gets
    0, not the new default, so that it is estimated again as it was; a result that
    records the setting keeps its value."""
    import json

    from lfsf import SceneFlow

    old = Params.preset("fast").as_dict()
    del old["flow_range_share"]
    assert Params.recorded(old) == Params.preset("fast").replace(flow_range_share=0.0)
    assert Params.recorded(Params.preset("fast").as_dict()) == Params.preset("fast")
    zeros = np.zeros((4, 6), np.float32)
    SceneFlow(zeros, zeros, zeros, zeros, params=Params.preset("fast"), radius=2.0, device="cpu").save(tmp_path / "r")
    saved = dict(np.load(tmp_path / "r/sceneflow.npz"))
    meta = json.loads(str(saved["params"]))
    del meta["params"]["flow_range_share"]
    saved["params"] = np.str_(json.dumps(meta))
    np.savez_compressed(tmp_path / "r/sceneflow.npz", **saved)
    assert SceneFlow.load(tmp_path / "r").params.flow_range_share == 0.0
    assert Params.from_toml(tmp_path / "r").flow_range_share == 0.0


def test_a_params_key_is_the_same_in_every_process_and_differs_with_any_setting():
    """``hash()`` of a Params differs from process to process (Python hashes None anew in
    each): a sweep's stored results keyed by it missed. ``key()`` is stable."""
    import subprocess
    import sys

    fast = Params.preset("fast")
    code = "from lfsf import Params; print(Params.preset('fast').key(), Params.preset('fast').replace(lambda1=2).key())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == [fast.key(), fast.replace(lambda1=2).key()] and out[0] != out[1]
    assert fast.replace(warps=3.0).key() == fast.key() and len(fast.key()) == 16
    assert len({Params.preset(name).key() for name in PRESETS}) == len(PRESETS)


def test_the_presets_cannot_be_changed_for_the_whole_process():
    """``PRESETS["fast"]["warps"] = 9`` had changed every later ``Params.preset("fast")``
    (in forked workers too, not in spawned ones)."""
    with pytest.raises(TypeError):
        PRESETS["fast"]["warps"] = 9
    with pytest.raises(TypeError):
        PRESETS["mine"] = {}
    assert Params.preset("fast").warps == 3


@pytest.mark.parametrize("changes, message", [
    ({"max_levels": 10 ** 400}, "max_levels must be in 0…10000, got 1.00e400"),
    ({"warm_levels": 1e300}, "warm_levels must be in 0…10000"),
    ({"min_size": 1e300}, "min_size must be in 4…65536 px"),
    ({"circles": 1e300}, "circles (M) must be in 1…256, got 1.00e300"),
    ({"alpha0": 0}, "alpha0 must be positive, got 0"),
    ({"alpha1": 0}, "alpha1 must be positive, got 0"),
    ({"samples": (1, 16)}, "M = 3, N = (1, 16) (set circles = 2 with these samples)"),
])
def test_settings_out_of_range_say_which_and_what_to_do(changes, message):
    """Bounds for the pyramid's settings (1e300 had been taken, and shown with its 300
    digits); alpha0 = 0 named neither setting; samples alone did not say that circles
    must follow."""
    with pytest.raises(ValueError) as caught:
        Params.preset("paper").replace(**changes)
    assert message in str(caught.value) and len(str(caught.value)) < 300, str(caught.value)


def test_a_setting_of_no_such_name_is_refused_with_the_nearest_names_however_params_is_made():
    """``Params(lamda1=3)`` and ``dataclasses.replace`` had been Python's TypeError with no
    hint, where ``.replace`` and TOML files say "did you mean lambda1?"; the constructor's
    signature and positional use are as before."""
    import inspect

    for make in (lambda: Params(lamda1=3), lambda: dataclasses.replace(Params(), lamda1=3),
                 lambda: Params.preset("fast").replace(lamda1=3), lambda: Params(**{**Params().as_dict(), "lamda1": 3})):
        with pytest.raises(ValueError, match=r"unknown parameter\(s\) lamda1 \(lamda1: did you mean lambda1\?\)"):
            make()
    assert list(inspect.signature(Params).parameters)[:3] == ["circles", "samples", "radius"]
    assert Params(2, (1, 8)) == Params.preset("paper").replace(circles=2, samples=(1, 8))
