"""Device choice and banded CPU launches."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lfsf import device as D
from lfsf import synth


def test_default_device_is_cuda_when_present(monkeypatch):
    monkeypatch.delenv(D.ENV_DEVICE, raising=False)
    want = "cuda:0" if "cuda:0" in D.available_devices() else "cpu"
    assert D.resolve_device() == want
    assert D.resolve_device("cpu") == "cpu"


def test_environment_variable_chooses_device(monkeypatch):
    monkeypatch.setenv(D.ENV_DEVICE, "cpu")
    assert D.resolve_device() == "cpu"
    monkeypatch.setenv(D.ENV_DEVICE, "cuda:7")
    with pytest.raises(ValueError, match=r"device 'cuda:7' \(from \$LFSF_DEVICE\) is not on this machine"):
        D.resolve_device()
    assert D.resolve_device("cpu") == "cpu"  # the argument wins over the environment


@pytest.mark.parametrize("name", ["gpu", "tpu:0", "cuda:x"])
def test_unknown_device_is_a_clear_error(name):
    with pytest.raises(ValueError, match=f"^unknown device '{name}': this machine has cpu"):
        D.resolve_device(name)


def test_a_cuda_device_not_here_is_said_to_be_absent_not_unknown():
    with pytest.raises(ValueError, match=r"^device 'cuda:9' is not on this machine, which has cpu"):
        D.resolve_device("cuda:9")
    if not D.warp().is_cuda_available():
        with pytest.raises(ValueError, match=r"^device 'cuda' is not on this machine, which has cpu \(Warp finds no "
                                             r"CUDA device: no NVIDIA GPU or driver\)$"):
            D.resolve_device("cuda")


@pytest.mark.parametrize("rows,bands", [(10, 3), (2, 8), (7, 1), (100, 7)])
def test_row_bands_cover_rows_once(rows, bands):
    parts = D.row_bands(rows, bands)
    assert parts[0][0] == 0 and parts[-1][1] == rows
    assert all(a < b for a, b in parts)
    assert all(p[1] == q[0] for p, q in zip(parts, parts[1:]))
    assert len(parts) <= bands


def test_banded_and_single_launches_give_identical_results():
    from lfsf.kernels import render

    wp = D.warp()
    cam = synth.CameraArray.for_size(48, 36)
    objs, _ = synth._scene_arrays(synth.get_scene("paper"), cam, "cpu")
    wcam = synth._warp_camera(cam)
    results = []
    for bands in (1, 2, 5):
        views = wp.zeros((9, 36, 48, 1), dtype=float, device="cpu")
        no_images = wp.zeros((1, 1, 1, 3), dtype=float, device="cpu")
        D.launch_rows(render.render_views, dim=(9 * 36, 48), inputs=[wcam, objs, 3, 1.0, 1.0, 2, no_images],
                      outputs=[views], device="cpu", bands=bands)
        results.append(views.numpy())
    assert np.all(results[0] != 0)
    np.testing.assert_array_equal(results[0], results[1])
    np.testing.assert_array_equal(results[0], results[2])


def test_generic_kernels_launch_through_their_cached_overload(device, monkeypatch):
    """launch_rows launches a generic kernel (unknowns of dtype=Any) through the overload
    for its arguments' types, found once: the same results as Warp's own inference, one
    overload for vec4 and another for vec2, and no inference on later launches. A kernel
    that is not generic is launched as it is."""
    from lfsf.kernels import tgv

    wp = D.warp()
    r = np.random.default_rng(4)
    h, w = 5, 7
    tensors = [wp.array(r.random((h, w, 3)).astype(np.float32), dtype=wp.vec3, device=device) for _ in range(3)]
    for vec in (wp.vec4, wp.vec2):
        ours = [wp.zeros((h, w), dtype=vec, device=device) for _ in range(3)]
        D.launch_rows(tgv.expand_tensor, (h, w), tensors, ours, device)
        theirs = [wp.zeros((h, w), dtype=vec, device=device) for _ in range(3)]
        wp.launch(tgv.expand_tensor, dim=(h, w), inputs=[0, *tensors], outputs=theirs, device=device)
        for a, b in zip(ours, theirs):
            np.testing.assert_array_equal(a.numpy(), b.numpy())
            assert np.any(a.numpy() != 0)
    overloads = {k: v for k, v in D._overloads.items() if k[0] is tgv.expand_tensor}
    assert len({id(v) for v in overloads.values()}) == 2 and not any(v.is_generic for v in overloads.values())

    def no_inference(*_args):
        raise AssertionError("types inferred again")

    monkeypatch.setattr(type(tgv.expand_tensor), "infer_argument_types", no_inference)
    D.launch_rows(tgv.expand_tensor, (h, w), tensors, ours, device)
    from lfsf.kernels import sampling

    assert D.resolved_kernel(sampling.sample_subaperture, [0]) is sampling.sample_subaperture  # not generic


def test_thread_count_from_environment(monkeypatch):
    monkeypatch.setenv(D.ENV_THREADS, "3")
    assert D.cpu_threads() == 3
    monkeypatch.setenv(D.ENV_THREADS, "many")
    with pytest.raises(ValueError, match="LFSF_THREADS"):
        D.cpu_threads()
    for bad in ("0", "-3", "1000"):
        monkeypatch.setenv(D.ENV_THREADS, bad)
        with pytest.raises(ValueError, match=r"LFSF_THREADS must be in 1…256"):
            D.cpu_threads()


def test_importing_lfsf_compiles_nothing_and_skips_warp():

    code = "import sys, lfsf; print('warp' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("bands", [1, 2, 5])
def test_recorded_launches_replay_as_plain_launches(bands):
    """RecordedRows (and CapturedLoop over it: a graph where the launches are single, a
    loop over the bands otherwise) gives what the same launch_rows calls give, as often
    as asked; the recorded arguments see the arrays' current contents."""
    from lfsf.kernels import tgv

    wp = D.warp()
    h, w = 9, 11
    r = np.random.default_rng(5)
    image = r.random((h, w)).astype(np.float32)
    a = wp.array(image, dtype=float, device="cpu")
    plain = wp.zeros((h, w), dtype=wp.vec3, device="cpu")
    replay = wp.zeros((h, w), dtype=wp.vec3, device="cpu")
    D.launch_rows(tgv.diffusion_tensor, dim=(h, w), inputs=[a, 5.0, 0.7], outputs=[plain], device="cpu")
    step = D.RecordedRows(tgv.diffusion_tensor, (h, w), inputs=[a, 5.0, 0.7], outputs=[replay], device="cpu",
                          bands=bands)
    assert step.single == (bands == 1)
    np.testing.assert_array_equal(replay.numpy(), 0.0)  # recording launches nothing
    step()
    np.testing.assert_array_equal(replay.numpy(), plain.numpy())
    # new contents of the same array are seen by the replay
    a.assign(image[::-1].copy())
    D.launch_rows(tgv.diffusion_tensor, dim=(h, w), inputs=[a, 5.0, 0.7], outputs=[plain], device="cpu")
    D.CapturedLoop([step], device="cpu").run(1)
    np.testing.assert_array_equal(replay.numpy(), plain.numpy())


@pytest.mark.parametrize("bands", [1, 2])
def test_captured_loop_runs_its_steps_n_times_in_order(bands, monkeypatch):
    """Two dependent steps (the TGV dual then primal step) n times through CapturedLoop
    equal n rounds of plain launches; n = 0 runs nothing."""
    from lfsf.kernels import tgv

    wp = D.warp()
    h, w = 6, 7
    r = np.random.default_rng(6)

    def fields():
        return {k: r.standard_normal((h, w, 4)).astype(np.float32) * 0.5
                for k in ("x", "w0", "w1", "y0", "y1", "z00", "z01", "z10", "z11", "grad")}

    start = fields()
    tensor = np.stack([np.ones((h, w)), np.zeros((h, w)), np.ones((h, w))], -1).astype(np.float32)
    steps_ = {k: np.full((h, w, 4), 0.2, np.float32) for k in ("sy", "tx", "tw0", "tw1")}

    def buffers():
        b = {k: wp.array(v, dtype=wp.vec4, device="cpu") for k, v in start.items()}
        b.update({k + "_bar": wp.array(start[k], dtype=wp.vec4, device="cpu") for k in ("x", "w0", "w1")})
        b.update({k: wp.array(v, dtype=wp.vec4, device="cpu") for k, v in steps_.items()})
        t = wp.array(tensor, dtype=wp.vec3, device="cpu")
        b["g"] = [wp.empty((h, w), dtype=wp.vec4, device="cpu") for _ in range(3)]
        D.launch_rows(tgv.expand_tensor, dim=(h, w), inputs=[t, t, t], outputs=b["g"], device="cpu")
        return b

    def args(b):
        dual = ([b["x_bar"], b["w0_bar"], b["w1_bar"], *b["g"], b["sy"], 0.25, 2.0, 0.5, w],
                [b["y0"], b["y1"], b["z00"], b["z01"], b["z10"], b["z11"]])
        primal = ([b["grad"], b["y0"], b["y1"], b["z00"], b["z01"], b["z10"], b["z11"], *b["g"],
                   b["tx"], b["tw0"], b["tw1"], wp.vec4(2.0, 2.0, 1.0, 1.0), 0.5, w],
                  [b["x"], b["w0"], b["w1"], b["x_bar"], b["w0_bar"], b["w1_bar"]])
        dual_step, primal_step = tgv.tgv_kernels("cpu")
        return [(dual_step, *dual), (primal_step, *primal)]

    plain = buffers()
    for _ in range(3):
        for kernel, inputs, outputs in args(plain):
            D.launch_rows(kernel, dim=(h, 1), inputs=inputs, outputs=outputs, device="cpu", bands=bands)
    assert not np.array_equal(plain["x"].numpy(), start["x"])
    # the CPU calls the steps in turn (CPU_CAPTURE); captured (as CUDA does), where no other
    # thread could launch meanwhile, the graph gives the same
    for capture, alone in ((False, True), (True, True), (True, False)):
        monkeypatch.setattr(D, "CPU_CAPTURE", capture)
        monkeypatch.setattr(D, "_alone", lambda: alone)
        replayed = buffers()
        loop = D.CapturedLoop([D.RecordedRows(k, (h, 1), inputs=i, outputs=o, device="cpu", bands=bands)
                               for k, i, o in args(replayed)], device="cpu")
        loop.run(0)
        np.testing.assert_array_equal(replayed["x"].numpy(), start["x"])
        loop.run(2)
        loop.run(1)
        assert (loop.graph is not None) == (capture and alone and bands == 1)
        for k in ("x", "w0", "w1", "y0", "z11"):
            np.testing.assert_array_equal(replayed[k].numpy(), plain[k].numpy(), err_msg=k)
    assert not D.warp().get_device("cpu").is_capturing


def test_estimates_in_several_threads_give_their_own_results():
    """Library calls are safe from several threads (README): four estimates running at
    once, six times each, give what each gives alone. With the CPU's loops captured as
    graphs this crashed the process (std::bad_alloc, a segmentation fault) or mixed the
    maps within seconds: Warp's CPU capture records the launches of every thread. In a
    child process, so that a crash fails this test alone."""
    code = """
import threading, numpy as np
from lfsf import estimate_scene_flow, synth
scenes, presets = ["paper", "slanted", "random-1", "random-2"], ["fast", "flow", "fast", "flow"]
pairs = [synth.render_scene(s, size=(48, 36), grid=5, device="cpu")[:2] for s in scenes]
alone = [estimate_scene_flow(*p, pr, device="cpu") for p, pr in zip(pairs, presets)]
differ = []
def work(k):
    for _ in range(6):
        sf = estimate_scene_flow(*pairs[k], presets[k], device="cpu")
        differ.extend(n for n in ("disp1", "disp2", "u", "v") if not np.array_equal(getattr(sf, n), getattr(alone[k], n)))
threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print("differ:", differ)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0 and out.stdout.strip() == "differ: []", (out.returncode, out.stdout, out.stderr[-2000:])


def test_the_submodules_are_attributes_of_lfsf_imported_on_first_use():
    """``import lfsf`` then ``lfsf.synth.render_scene`` (an AttributeError before, reading
    as if the module did not exist), still without importing Warp until a submodule that
    needs it is used; a name that is neither is an AttributeError."""

    code = ("import sys, lfsf; assert 'lfsf.synth' not in sys.modules; "
            "print(lfsf.synth.__name__, lfsf.viz.flow_to_color.__name__, 'synth' in dir(lfsf), 'warp' in sys.modules)\n"
            "try:\n    lfsf.nothing\nexcept AttributeError as e:\n    print(e)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.splitlines() == ["lfsf.synth flow_to_color True False", "module 'lfsf' has no attribute 'nothing'"]


def test_preload_compiles_several_modules_at_once_into_the_cache(tmp_path):
    """:func:`lfsf.device.preload` on a cold kernel cache compiles every module it is
    given (each one's folder appears in the cache), the kernels then launch, and a second
    call skips the modules already loaded (0 s)."""
    import os

    code = (
        "import numpy as np\n"
        "from lfsf import device as D\n"
        "from lfsf.kernels import fusion, pyramid\n"
        "wp = D.warp()\n"
        "cold = D.cold_modules([pyramid, fusion], 'cpu')\n"
        "said = []\n"
        "first = D.preload([pyramid, fusion], 'cpu', announce=said.append)\n"
        "again = D.preload([fusion, pyramid], 'cpu', announce=said.append)\n"
        "src = wp.array(np.arange(48, dtype=np.float32).reshape(1, 6, 8), dtype=float, device='cpu')\n"
        "out = wp.empty((1, 6, 8), dtype=float, device='cpu')\n"
        "D.launch_rows(pyramid.upsample, dim=(6, 8), inputs=[src, 2.0], outputs=[out], device='cpu')\n"
        "print(first > 0.0, again == 0.0, np.array_equal(out.numpy(), 2 * src.numpy()))\n"
        "print(*cold, *D.cold_modules([pyramid, fusion], 'cpu') or ['none'])\n"
        "print(said == [cold])\n"   # (announced once, before the compile: the cold ones)
    )
    env = {**os.environ, "WARP_CACHE_PATH": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "True", "True", "lfsf.kernels.pyramid", "lfsf.kernels.fusion", "none",
                                  "True"]
    compiled = {p.name.rsplit("_", 1)[0] for p in tmp_path.rglob("wp_lfsf.kernels.*") if p.is_dir()}
    assert compiled == {"wp_lfsf.kernels.pyramid", "wp_lfsf.kernels.fusion"}
    # a cache entry damaged (a copy cut short, a network file system's fault): it had been a
    # traceback ("Expecting value: line 1 column 1") or "Failed to load CPU module", every run
    (meta,) = tmp_path.rglob("wp_lfsf.kernels.fusion_*/*.meta")
    meta.write_text("garbage")
    code = "from lfsf import device as D\nfrom lfsf.kernels import fusion\nD.preload([fusion], 'cpu')\n"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode != 0 and f"OSError: Warp's kernel cache {meta.parent.parent} holds a damaged entry of " \
        f"lfsf's kernels (Expecting value" in out.stderr, out.stderr
    assert f"(rm -r {meta.parent.parent / 'wp_lfsf.kernels.*'}), and they are compiled again" in out.stderr


def test_a_kernel_cache_that_cannot_be_made_is_one_line(tmp_path):
    """WARP_CACHE_PATH on a file (or HOME read-only): one line naming the folder, which had
    started with "[Errno 20]" and ended with the file's name in quotes."""
    (tmp_path / "file").write_text("")
    env = {**os.environ, "WARP_CACHE_PATH": str(tmp_path / "file")}
    out = subprocess.run([sys.executable, "-m", "lfsf", "run", "a.npz", "b.npz", "--out", str(tmp_path / "o")],
                         capture_output=True, text=True, env=env)
    assert out.returncode == 2 and out.stderr.startswith(f"lfsf run: error: Warp cannot set up its kernel cache "
                                                         f"{tmp_path / 'file'}"), out.stderr
    assert "[Errno" not in out.stderr and out.stderr.rstrip().endswith("set WARP_CACHE_PATH to a writable folder")


def test_a_kernel_cache_that_cannot_take_the_kernels_is_named(monkeypatch):
    """A full or read-only kernel cache: the compiler had ended the process with LLVM's own
    "IO failure on output stream", or the message named a build folder of Warp's, or
    blamed the outputs (a helper's full home quota and read-only shared cache). Other
    errors of the compile go on as they were."""
    import errno
    import json
    import shutil

    wp = D.warp()
    cache = wp.config.kernel_cache_dir
    with monkeypatch.context() as patched:
        patched.setattr(shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(1 << 30, 1 << 30, 200 << 10))
        with pytest.raises(OSError, match=f"Warp's kernel cache {cache}: 200 KB free, where lfsf's kernels need "
                                          f"about 64 MB to be compiled into it"):
            D._check_cache_room(cache)

    class Module:  # (not a Warp module: no cache folder to look for, no room checked)
        name = "lfsf.kernels.x"

    class New(Module):  # (a module of no build in the cache: compiled in this call)
        options = {"block_dim": 256}

        def get_module_identifier(self, block_dim=None):
            return "wp_lfsf.kernels.x_0000000"

    build = os.path.join(cache, "wp_x_p1_t2")
    failed = "Failed to load CPU module 'lfsf.kernels.x' (device='cpu')"
    for module, raised, said in (
            (Module, OSError(errno.EACCES, "Permission denied", build),
             f"Warp's kernel cache {cache}: Permission denied ({build}) while compiling"),
            (Module, OSError(errno.ENOSPC, "No space left on device", build), f"{cache}: No space left on device"),
            (Module, OSError(errno.EACCES, "Permission denied", "/elsewhere"), None),  # (not the cache's: as it was)
            (Module, Exception(failed), "a damaged entry"),
            (New, Exception(failed), None),  # (compiled just now: no deleting mends it)
            (Module, json.JSONDecodeError("Expecting value", "", 0), "a damaged entry"),
            (Module, RuntimeError("a kernel's own error"), None),
            (Module, ValueError("codegen"), None),
            # (a cache path of undecoded bytes under the C locale, which Warp hands its compiler as UTF-8)
            (Module, UnicodeEncodeError("utf-8", "cach\udcc3", 4, 5, "surrogates not allowed"),
             f"Warp's kernel cache {cache}: its path cannot be handed to Warp's compiler (surrogates not allowed)")):
        def load(raised=raised, **_):
            raise raised

        monkeypatch.setattr(wp, "force_load", load)
        monkeypatch.setattr(D, "_check_cache_room", lambda cache: None)
        with pytest.raises(Exception) as info:
            D._load([module()], wp.get_device("cpu"))
        if said is None:
            assert info.value is raised
        else:
            assert type(info.value) is OSError and said in str(info.value), info.value


def test_without_a_home_folder_the_kernel_cache_is_the_users_own_temporary_one(monkeypatch, tmp_path):
    """HOME unset and no passwd entry: ``~`` stays ``~``, and Warp had made a folder named
    ``~`` in the current folder; HOME=/ (``docker run --user 12345``), not writable: Warp
    could not start. A temporary folder of this user's alone serves instead; one that
    others may write into, or a link, is refused (its code is run). A home folder that
    holds Warp's cache already keeps it, writable or not (a shared, warm one)."""
    import tempfile

    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    home = tmp_path / "home"
    home.mkdir()
    writable = [True]
    monkeypatch.setattr(os, "access", lambda path, mode: writable[0] or not str(path).startswith(str(home)))
    monkeypatch.setattr(os.path, "expanduser", lambda path: path.replace("~", str(home)))
    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    folder = tmp_path / f"lfsf-warp-cache-{os.getuid()}"
    assert D._cache_without_home("1.19.0") is None              # (Warp's own ~/.cache/warp can be made)
    for xdg in ("", "relative"):  # (ignored, as the XDG rules say: Warp had made the folder in the current one)
        monkeypatch.setenv("XDG_CACHE_HOME", xdg)
        assert D._cache_without_home("1.19.0") == str(home / ".cache" / "warp")
    monkeypatch.delenv("XDG_CACHE_HOME")
    (home / ".cache").symlink_to(tmp_path / "nowhere")   # (a link to nothing: cannot be made)
    assert D._cache_without_home("1.19.0") == str(folder) and folder.stat().st_mode & 0o777 == 0o700
    (home / ".cache").unlink()
    writable[0] = False
    assert D._cache_without_home("1.19.0") == str(folder)
    (home / ".cache" / "warp").mkdir(parents=True)
    assert D._cache_without_home("1.19.0") == str(folder)       # (not this Warp's, and not writable)
    (home / ".cache" / "warp" / "1.19.0").mkdir()
    assert D._cache_without_home("1.19.0") is None              # (this Warp's there already: read, as before)
    monkeypatch.setattr(os.path, "expanduser", lambda path: path)   # (no home at all)
    assert D._cache_without_home("1.19.0") == str(folder)       # (found again)
    folder.chmod(0o777)
    with pytest.raises(OSError, match="is not this user's alone"):
        D._cache_without_home("1.19.0")
    folder.rmdir()
    folder.symlink_to(home)
    with pytest.raises(OSError, match=r"is not a folder \(a link, or a file\)"):
        D._cache_without_home("1.19.0")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert D._cache_without_home() is None


def test_on_macos_the_kernel_cache_probed_is_warps_own_there(monkeypatch, tmp_path):
    """Warp's cache on macOS is ~/Library/Caches/warp, XDG_CACHE_HOME or not: lfsf had
    probed ~/.cache, and moved the cache to the temporary folder (purged there) where
    that was not writable, or forced ~/.cache/warp for an empty XDG_CACHE_HOME."""
    import tempfile

    home = tmp_path / "home"
    (home / ".cache").mkdir(parents=True)
    monkeypatch.setattr(sys, "platform", "darwin")
    monkeypatch.setattr(os.path, "expanduser", lambda path: path.replace("~", str(home)))
    monkeypatch.setattr(tempfile, "gettempdir", lambda: str(tmp_path))
    monkeypatch.setattr(os, "access", lambda path, mode: not str(path).startswith(str(home / ".cache")))
    for xdg in ("", "relative", None):
        if xdg is None:
            monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
        else:
            monkeypatch.setenv("XDG_CACHE_HOME", xdg)
        assert D._cache_without_home("1.19.0") is None   # (~/Library/Caches/warp can be made)


def test_a_file_on_another_drive_is_not_within_the_cache(monkeypatch):
    """Windows' commonpath raises ValueError for paths on two drives: it had replaced the
    error it was asked about."""
    def two_drives(paths):
        raise ValueError("Paths don't have the same drive")

    monkeypatch.setattr(os.path, "commonpath", two_drives)
    assert D._within("D:/cache/x", "C:/cache") is False


def test_the_estimator_preloads_every_kernel_module_it_imports():
    """:func:`lfsf.estimate.kernel_modules` (what the estimator compiles at its start)
    names every module with kernels that the estimator's code imports from
    :mod:`lfsf.kernels`: one left out would still compile at its first launch, but alone."""
    import ast
    import importlib
    from pathlib import Path

    from lfsf.estimate import kernel_modules

    root = Path(__file__).resolve().parents[1] / "lfsf"
    imported = set()
    for name in ("estimate.py", "solver.py", "gains.py", "_filters.py"):
        for node in ast.walk(ast.parse((root / name).read_text())):
            if isinstance(node, ast.ImportFrom) and node.module == "lfsf.kernels":
                imported.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("lfsf.kernels."):
                imported.add(node.module.split(".")[2])
    with_kernels = {n for n in imported if "@wp.kernel" in Path(importlib.import_module(f"lfsf.kernels.{n}").__file__)
                    .read_text()}
    assert {"data_term", "tgv", "search"} <= with_kernels  # (the walk found the imports)
    assert with_kernels == {m.__name__.rsplit(".", 1)[1] for m in kernel_modules("cpu")}
    assert "data_groups" not in {m.__name__.rsplit(".", 1)[1] for m in kernel_modules("cuda:0")}


def test_a_warp_too_old_is_a_clear_error(monkeypatch):
    """An installed Warp older than MIN_WARP (pyproject's warp-lang>=) is an ImportError
    naming the version found and the upgrade, raised before Warp starts, and again when
    the kernels are imported (the estimator imports them before it starts Warp)."""
    import importlib
    import re

    import warp

    least = ".".join(map(str, D.MIN_WARP))
    D.require_warp(least)
    D.require_warp("99.0.0")
    for old in ("1.5.0", f"{D.MIN_WARP[0]}.{D.MIN_WARP[1] - 1}.2"):
        message = f"lfsf needs warp-lang {least} or newer, and this Python has {old}: pip install -U 'warp-lang>={least}'"
        with pytest.raises(ImportError, match=re.escape(message)):
            D.require_warp(old)
    monkeypatch.setattr(warp, "__version__", "1.5.0")
    monkeypatch.setattr(D, "_initialised", False)
    with pytest.raises(ImportError, match="this Python has 1.5.0"):
        D.warp()
    monkeypatch.delitem(sys.modules, "lfsf.kernels", raising=False)  # (imported or not before)
    with pytest.raises(ImportError, match="this Python has 1.5.0"):
        importlib.import_module("lfsf.kernels")


def test_a_warp_too_old_is_one_line_from_the_cli(monkeypatch, tmp_path, capsys):
    """From the command line a too-old Warp ends as bad input does: one line naming the
    version and the upgrade, status 2, no traceback, nothing written."""
    import warp

    from lfsf.cli import main

    monkeypatch.setattr(warp, "__version__", "1.5.0")
    monkeypatch.setattr(D, "_initialised", False)
    out = tmp_path / "scene"
    status = main(["synth", "slanted", "--out", str(out), "--size", "32", "24", "--grid", "3", "--quiet"])
    err = capsys.readouterr().err
    assert status == 2
    assert err.splitlines() == [f"lfsf synth: error: lfsf needs warp-lang {'.'.join(map(str, D.MIN_WARP))} or newer, "
                                f"and this Python has 1.5.0: pip install -U 'warp-lang>="
                                f"{'.'.join(map(str, D.MIN_WARP))}'"]
    assert not out.exists()


def _estimate_in_child(queue):
    import lfsf
    from lfsf import synth

    lf1, lf2, _ = synth.render_scene("paper", size=(64, 48), grid=3, device="cpu")
    sf = lfsf.estimate_scene_flow(lf1, lf2, "fast", device="cpu")
    queue.put(sf.u.tobytes())


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no fork here")
def test_a_forked_child_estimates_after_its_parent_did():
    """multiprocessing's "fork" start after lfsf ran in the parent: the child had inherited
    the parent's band pool without its threads, and its first banded launch waited for ever.
    The child gives the parent's result."""
    import multiprocessing
    import warnings

    import lfsf
    from lfsf import synth

    lf1, lf2, _ = synth.render_scene("paper", size=(64, 48), grid=3, device="cpu")
    mine = lfsf.estimate_scene_flow(lf1, lf2, "fast", device="cpu").u
    assert D._pool is not None  # (the parent's pool exists: what the child inherits)
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # (3.12+: fork of a process with threads)
        child = context.Process(target=_estimate_in_child, args=(queue,))
        child.start()
    try:
        got = queue.get(timeout=240)
    finally:
        child.join(timeout=10)
        if child.is_alive():
            child.kill()
    assert got == mine.tobytes()


def test_a_compile_is_announced_before_it_starts(monkeypatch):
    """On a cold kernel cache 10–20 s had passed without a word before "kernels compiled
    for cpu in … s" (a helper, pressing Ctrl-C meanwhile)."""
    from lfsf import estimate

    told, cold = [], []

    def preload(modules, device, announce=None):   # (as lfsf.device._load: the cold ones announced, then compiled)
        if cold and announce is not None:
            announce(cold)
        told.append("preload")
        return 2.5

    monkeypatch.setattr(D, "preload", preload)
    cold[:] = ["lfsf.kernels.tgv", "lfsf.kernels.rof", "lfsf.kernels.median"]
    assert estimate.load_kernels("cpu", say=told.append) == ("kernels compiled for cpu in 2.5 s (once: Warp's "
                                                              "kernel cache keeps them)")
    assert told == ["compiling the kernels for cpu (3 modules; the first run only)…", "preload"]
    cold.clear()
    told.clear()
    estimate.load_kernels("cpu", say=told.append)
    assert told == ["preload"]


def test_a_thread_that_waits_for_another_threads_compile_is_told_the_modules_being_compiled(monkeypatch):
    """Two estimates in two threads on a cold cache: the thread that waited for the
    other's compile (14.5 s) had been told nothing; it is told of the modules being
    compiled, does not compile them again, and counts the wait in its seconds."""
    import threading
    import time

    compiled, told = [], []
    started = threading.Event()

    class Module:
        def __init__(self, name):
            self.name = name

    modules = [Module("lfsf.kernels.tgv"), Module("lfsf.kernels.rof")]

    def compile_slowly(wp, todo, device):
        compiled.append([m.name for m in todo])
        started.set()
        time.sleep(0.5)

    monkeypatch.setattr(D, "_compile", compile_slowly)
    monkeypatch.setattr(D, "_loaded", set())  # (these stand-ins' ids are not kept as loaded modules')
    monkeypatch.setattr(D, "_cold", lambda todo, device: list(todo))
    monkeypatch.setattr(D, "_check_cache_room", lambda cache: None)
    monkeypatch.setattr(D, "_remove_dead_builds", lambda cache: None)
    first = threading.Thread(target=D._load, args=(modules, "cpu", lambda names: told.append(("first", names))))
    first.start()
    assert started.wait(10)
    waited = D._load(modules, "cpu", lambda names: told.append(("second", names)))
    first.join()
    names = ["lfsf.kernels.tgv", "lfsf.kernels.rof"]
    assert told == [("first", names), ("second", names)] and compiled == [names]
    assert waited > 0.1 and D._compiling is None
    assert D._load(modules, "cpu", lambda names: told.append(("third", names))) == 0.0 and len(told) == 2


@pytest.mark.parametrize("device, heard", [("cpu", [["lfsf.kernels.tgv"]]), ("cuda:0", [])])
def test_a_waiting_thread_is_told_once_the_compile_knows_its_modules_and_only_of_its_devices(monkeypatch, device,
                                                                                              heard):
    """A thread that began to wait before the compiling one knew its modules (hashing them,
    under the lock) is told once it does; a compile for another device is not its own."""
    import threading
    import time

    said = []
    ready = threading.Event()

    def holder():
        with D._init_lock:
            ready.set()
            time.sleep(0.3)
            monkeypatch.setattr(D, "_compiling", ("cpu", ("lfsf.kernels.tgv",)))
            time.sleep(0.5)
            monkeypatch.setattr(D, "_compiling", None)

    thread = threading.Thread(target=holder)
    thread.start()
    assert ready.wait(10)
    waited = D._wait_for_compile(device, said.append)
    thread.join()
    assert said == heard and (waited > 0.3) == bool(heard), (device, said, waited)


@pytest.mark.parametrize("how", ["signal", "interrupt_main"])
def test_a_ctrl_c_during_the_compile_waits_only_for_the_modules_being_compiled(monkeypatch, how):
    """Warp's own pool compiled every module given before a Ctrl-C could end the process
    (12.7 s on a first run's 12 modules, 2 cores). Now the modules not begun are
    cancelled: the interrupt comes after the modules being compiled, on their threads.
    So too an interrupt that comes as a flag, not a signal (``_thread.interrupt_main``,
    as a notebook's or an IDE's may): the wait had not woken for it until every module
    was compiled."""
    import _thread
    import signal
    import threading
    import time

    wp = D.warp()
    begun, lock = [], threading.Lock()

    def force_load(device=None, modules=(), max_workers=None, block_dim=None):
        with lock:
            begun.extend(m.name for m in modules)
            first = len(begun) == 1
        if first and how == "signal":  # (a Ctrl-C, delivered to the main thread, which waits for the modules)
            signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
        elif first:  # (once the main thread waits: a flag raised before is seen as it submits)
            threading.Timer(0.3, _thread.interrupt_main).start()
        time.sleep(1.0)

    class Module:
        def __init__(self, k):
            self.name = f"lfsf.kernels.m{k}"

    monkeypatch.setattr(wp, "force_load", force_load)
    monkeypatch.setattr(D, "cpu_threads", lambda: 2)
    with pytest.raises(KeyboardInterrupt):
        D._compile(wp, [Module(k) for k in range(8)], wp.get_device("cpu"))
    assert 1 <= len(begun) <= 2, begun   # (the two threads' first modules at most; all 8 before)
    # a module that fails cancels those not begun the same way, its error raised
    begun.clear()

    def fails(device=None, modules=(), max_workers=None, block_dim=None):
        with lock:
            begun.extend(m.name for m in modules)
        if modules[0].name == failing:
            raise RuntimeError("a kernel's own error")
        time.sleep(1.0)

    monkeypatch.setattr(wp, "force_load", fails)
    for failing in ("lfsf.kernels.m0", "lfsf.kernels.m1"):  # (not seen only once the modules before it ended)
        begun.clear()
        with pytest.raises(RuntimeError, match="a kernel's own error"):
            D._compile(wp, [Module(k) for k in range(8)], wp.get_device("cpu"))
        assert len(begun) <= 3, (failing, begun)


def test_an_interrupted_command_leaves_no_warp_temporaries(tmp_path, monkeypatch):
    """Warp keeps its precompiled headers in $TMPDIR/wp_pch_* for the process's life and
    removes them at exit; lfsf ends an interrupted command with os._exit, which had left
    them (8.9 MB a first run, a helper's SIGTERM and Ctrl-C). They go before the exit."""
    import tempfile

    from lfsf import cli

    wp = D.warp()
    runtime = sys.modules["warp._src.context"].runtime if "warp._src.context" in sys.modules else None
    if not isinstance(getattr(runtime, "_pch_dirs", None), dict):
        pytest.skip("this Warp keeps no precompiled-header folders")
    folder = tempfile.TemporaryDirectory(prefix="wp_pch_", dir=tmp_path)
    (Path(folder.name) / "header.pch").write_bytes(b"x" * 1000)
    monkeypatch.setattr(runtime, "_pch_dirs", {-1: folder})  # (this process's own stay)
    ended = []
    monkeypatch.setattr(cli.os, "_exit", ended.append)
    cli._exit_now(130)
    assert ended == [130] and not Path(folder.name).exists() and list(tmp_path.iterdir()) == []
    assert wp is D.warp()


def test_a_cache_filled_on_another_cpu_counts_as_cold_and_is_named(monkeypatch, tmp_path):
    """Warp names a module's CPU object by the CPU's target (``….cpu1a2b3c4d.o``), in a
    folder that machines sharing a cache share. A folder with another CPU's object alone
    had counted as built (the compile then ran unannounced), and where Warp could not add
    this CPU's object to another user's folder, lfsf called the entry damaged and said to
    delete everyone's (a helper's cluster of mixed CPUs)."""
    from lfsf.kernels import fusion

    wp = D.warp()
    cpu = wp.get_device("cpu")
    module = wp.get_module(fusion.__name__)
    monkeypatch.setattr(wp.config, "kernel_cache_dir", str(tmp_path))
    folder, binary = D._build(module, cpu)
    if binary is None:
        pytest.skip("this Warp does not name its CPU objects")
    assert Path(folder).parent == tmp_path and Path(binary).parent == Path(folder)
    assert D._cold([module], cpu) == [module]
    Path(folder).mkdir()
    (Path(folder) / Path(binary).name.replace(".cpu", ".cpuffff")).write_bytes(b"")  # (another CPU's)
    assert D._cold([module], cpu) == [module]
    Path(binary).write_bytes(b"")
    assert D._cold([module], cpu) == []
    Path(binary).unlink()

    def load(**_):  # (what Warp raises where it could not put this CPU's object in the folder)
        raise Exception(f"Failed to load CPU module '{module.name}' (device='cpu')")

    monkeypatch.setattr(wp, "force_load", load)
    monkeypatch.setattr(D, "_check_cache_room", lambda cache: None)
    monkeypatch.setattr(D, "_loaded", set())
    with pytest.raises(OSError, match=f"its entry {folder} holds lfsf's kernels built for another CPU, and this "
                                      f"CPU's could not be added to it .*: set WARP_CACHE_PATH to a folder of your "
                                      f"own$"):
        D._load([module], cpu)


def test_a_killed_compiles_build_folders_are_removed_by_a_later_compile(monkeypatch, tmp_path):
    """A process killed outright while it compiled left Warp's build folders
    (``wp_lfsf.kernels.X_HASH_pPID_tTID``) in the cache for good (a helper: two a kill).
    A later compile removes those of a gone process older than an hour; a live
    process's, a recent one's (another machine's, perhaps, on a shared cache) and
    anything else stay."""
    import subprocess
    import time

    gone = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)
    running = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    old = time.time() - 2 * D.DEAD_BUILD_AGE
    folders = {
        "dead": f"wp_lfsf.kernels.rof_f988f00_p{gone}_t140240488494784",
        "live": f"wp_lfsf.kernels.rof_f988f00_p{running.pid}_t1",
        "this process's": f"wp_lfsf.kernels.rof_f988f00_p{os.getpid()}_t1",
        "recent": f"wp_lfsf.kernels.tgv_0123abc_p{gone}_t2",
        "a module's own": "wp_lfsf.kernels.rof_f988f00",
        "another program's": f"wp_mine_0123abc_p{gone}_t3",
    }
    for name, folder in folders.items():
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "x.cpp").write_text("")
        if name != "recent":
            os.utime(tmp_path / folder, (old, old))
    try:
        D._remove_dead_builds(str(tmp_path))
    finally:
        running.kill()
        running.wait()
    assert {name for name, folder in folders.items() if (tmp_path / folder).exists()} == {
        "live", "this process's", "recent", "a module's own", "another program's"}
    D._remove_dead_builds(str(tmp_path / "missing"))  # (no cache folder: nothing to do)
