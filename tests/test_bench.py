"""`lfsf bench`: the rows INTERFACE.md promises, and figures that mean what they say.

Timings are never asserted (the machine is shared and noisy); what is checked is the
shape of the report, that the byte counts match the arrays the kernels touch, and that
the errors reported are the estimator's.
"""

import json
import os
import subprocess
import sys
import types

import numpy as np
import pytest

from lfsf import bench


def test_time_repeated_warms_up_then_times_each_run():
    calls = []
    warmups = []
    seconds, result = bench.time_repeated(lambda: calls.append(1) or len(calls), repeats=3, warmup=2,
                                          warmup_seconds=warmups)
    assert len(calls) == 5 and result == 5 and len(seconds) == 3 and all(s >= 0 for s in seconds)
    assert len(warmups) == 2 and all(s >= 0 for s in warmups)
    s = bench.summarise([3.0, 1.0, 2.0])
    # the runs themselves too, from which anyone can recompute the median and spread
    assert s == {"seconds_median": 2.0, "seconds_min": 1.0, "seconds_max": 3.0, "repeats": 3,
                 "seconds": [3.0, 1.0, 2.0]}


def test_kernel_cases_count_the_bytes_of_their_arrays():
    """The bytes a data-term step must move: coefficients (7 floats per sample), q read
    and written (3 + 3), the row flags (3 words for up to 31 samples), ∇J2 (2), x̄, x̂ and
    Kᵀq (4 each) per pixel; a TGV dual step's: x̄, w̄ (12), three tensors (9), σ_y (4), the
    six duals read and written (24 + 24)."""
    cases = {name: nbytes for name, _run, nbytes in bench.kernel_cases((20, 10), "cpu")}  # 17 samples
    assert set(cases) == {"sample_subaperture", "data_coefficients", "dual_data_step", "tgv_dual_step",
                          "tgv_primal_step"}
    assert cases["dual_data_step"] == 4 * 200 * (7 * 17 + 6 * 17 + 3 + 2 + 12)
    assert cases["tgv_dual_step"] == 4 * 200 * 73


def test_scene_inputs_are_the_last_warp_of_a_run_at_the_ground_truth(monkeypatch):
    """With the default inputs the data-term kernels run on a rendered scene's arrays as
    a run's last warp has them: the benchmarked launch gives the coefficients the solver
    itself computes, bit for bit, and the rows sit near zero residual, well below those
    of a linearisation point 1 px off in flow or 0.3 px per view step off in disparity
    (random inputs, ``inputs="random"``, are the worst case: no point matches)."""
    size = (48, 32)
    solver, views = bench._scene_solver(size, "cpu")
    assert views.shape == (81, 32, 48)
    expected = solver.coef_store.numpy().copy(), solver.flags_store.numpy().copy()
    monkeypatch.setattr(bench, "_scene_solver", lambda *_a, **_k: (solver, views))
    cases = {name: run for name, run, _n in bench.kernel_cases(size, "cpu")}
    solver.coef_store.zero_()
    solver.flags_store.zero_()
    cases["data_coefficients"]()
    np.testing.assert_array_equal(solver.coef_store.numpy(), expected[0])
    np.testing.assert_array_equal(solver.flags_store.numpy(), expected[1])

    def median_residuals(s):
        a, wt = s.data_rows()
        return np.median(np.abs(a[1])[wt[0] > 0]), np.median(np.abs(a[6])[wt[2] > 0])  # |A2| (ρ1), |A7| (ρ3)

    rho1, rho3 = median_residuals(solver)
    truth = solver.linearisation_point()
    from lfsf import synth

    gt = synth.render_scene("paper", size=size, grid=9, device="cpu")[2]
    np.testing.assert_array_equal(truth, np.stack([gt["disp1"], gt["disp2"], gt["u"], gt["v"]], -1))
    solver.set_state(truth + np.float32([0, 0, 1, 0]))
    solver.linearise()
    assert rho3 < 0.5 * median_residuals(solver)[1]
    solver.set_state(truth + np.float32([0.3, 0.3, 0, 0]))
    solver.linearise()
    assert rho1 < 0.5 * median_residuals(solver)[0]
    with pytest.raises(ValueError, match="inputs must be one of"):
        bench.kernel_cases(size, "cpu", inputs="noise")


@pytest.mark.parametrize("inputs", ["scene", "random"])
def test_bench_kernels_rows(inputs):
    rows = bench.bench_kernels((24, 16), "cpu", repeats=2, inputs=inputs)
    assert [r["kernel"] for r in rows][:2] == ["sample_subaperture", "data_coefficients"]
    for r in rows:
        assert r["inputs"] == inputs
        assert r["gbytes_per_s"] > 0 and r["memcpy_gbytes_per_s"] > 0
        assert r["seconds_min"] <= r["seconds_median"] <= r["seconds_max"]
        assert r["fraction_of_memcpy"] == pytest.approx(r["gbytes_per_s"] / r["memcpy_gbytes_per_s"], rel=0.01, abs=1e-3)
        # GB/s are the bytes over the median time (the key says so), not over the best
        assert r["gbytes_per_s"] == pytest.approx(r["bytes"] / r["seconds_median"] / 1e9, rel=0.01)


def test_the_copy_reference_moves_the_kernels_bytes(monkeypatch):
    """A kernel's bytes are what it reads and writes; the copy it is compared with reads
    and writes as many, i.e. copies half of them (a copy of all would read and write
    twice the kernel's bytes and halve the copy's GB/s)."""
    asked = []
    copies = bench._copies
    monkeypatch.setattr(bench, "_copies", lambda nbytes, *a, **k: (asked.append(nbytes), copies(nbytes, *a, **k))[1])
    rows = bench.bench_kernels((24, 16), "cpu", repeats=2, inputs="random")
    assert asked == [r["bytes"] // 2 for r in rows]


def test_bench_kernels_batches_short_launches(monkeypatch):
    """A launch shorter than MIN_SAMPLE_SECONDS is timed as the mean of a batch that
    fills it (a GPU's launches take microseconds); with the minimum at zero, a sample is
    one launch."""
    rows = bench.bench_kernels((24, 16), "cpu", repeats=2, inputs="random")
    # 24×16 launches take tens of microseconds (any: one may be slowed while calibrating)
    assert any(r["launches_per_sample"] > 1 for r in rows)
    monkeypatch.setattr(bench, "MIN_SAMPLE_SECONDS", 0.0)
    rows = bench.bench_kernels((24, 16), "cpu", repeats=2, inputs="random")
    assert all(r["launches_per_sample"] == 1 for r in rows)


def test_copy_references_copy_every_element(monkeypatch):
    """The copies that the kernels' bandwidth is measured against (one ``wp.copy``, and
    one per row band on the CPU's threads) each copy the whole array."""
    from lfsf import device

    monkeypatch.setenv("LFSF_THREADS", "2")
    wp = device.warp()
    n = 1001
    src = wp.array(np.arange(n, dtype=np.float32), dtype=float, device="cpu")
    names = list(bench._copies(4 * n, "cpu", src=src))
    assert names == ["wp.copy", "wp.copy in 2 bands"]
    for name in names:
        dst = wp.zeros(n, dtype=float, device="cpu")
        bench._copies(4 * n, "cpu", src=src, dst=dst)[name]()
        assert np.array_equal(dst.numpy(), src.numpy()), name


def test_bench_pipeline_reports_stages_memory_and_the_estimators_errors():
    from lfsf import synth
    from lfsf.estimate import estimate_scene_flow
    from lfsf.evaluate import evaluate
    from lfsf.params import Params

    settings = (("fast", "fast", {}),)
    rows = bench.bench_pipeline((48, 32), "cpu", repeats=2, settings=settings)
    (row,) = rows
    assert row["setting"] == "fast" and row["size"] == [48, 32] and row["views"] == 9
    assert row["repeats"] == 2 and row["peak_rss_mb"] > 10
    assert {"sampling", "texture", "iterate", "linearise"} <= set(row["stages"])
    assert sum(row["stages"].values()) <= row["seconds_max"] + 1e-3
    # with two runs the median is their mean, and so are the stages (they were the slower run's)
    assert abs(sum(row["stages"].values()) - row["seconds_median"]) < 0.25 * row["seconds_median"]
    assert row["peak_rss_scope"] in ("setting", "process")
    # the errors are those of the estimator on the same scene (deterministic on the CPU)
    lf1, lf2, gt = synth.render_scene("paper", size=(48, 32), grid=9)
    want = evaluate(estimate_scene_flow(lf1, lf2, Params.preset("fast"), device="cpu").as_dict(), gt, border=8)
    assert row["errors"]["flow"]["epe"] == pytest.approx(want["flow"]["epe"], abs=1e-5)
    # counts as whole numbers, as lfsf eval --json writes them (they were 652.0)
    assert row["errors"]["flow"]["pixels"] == want["flow"]["pixels"] and type(row["errors"]["flow"]["pixels"]) is int


def test_bench_pipeline_scores_a_flow_only_setting_on_its_flow_alone():
    """Its δ1 and δ2 are zeros, not estimates: no disparity errors in its row (they were
    scored, MSE 2.9 and BadPix 98 %), as lfsf eval leaves them out; the table draws a
    stage that a setting does not run as '–', not 0.00."""
    settings = (("paper", "paper", {}), ("flow only", "flow", {}))  # (the paper's views' gains: a stage of its own)
    rows = bench.bench_pipeline((96, 72), "cpu", repeats=1, settings=settings)
    assert {"disp1", "disp2", "flow"} <= set(rows[0]["errors"])
    assert "flow" in rows[1]["errors"] and not {"disp1", "disp2"} & set(rows[1]["errors"])
    table = bench.format_rows("pipeline", rows).splitlines()
    missing = [k for k in rows[0]["stages"] if k not in rows[1]["stages"]]
    assert missing, "the flow preset runs every stage of paper"
    # the stages' table: a row per stage, a column per setting
    start = table.index("| stage, seconds | paper | flow only |")
    cells = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
             for line in table[start + 2:] if line.startswith("|")}
    assert set(cells) == set(rows[0]["stages"]) | set(rows[1]["stages"])
    assert all(cells[k][1] == "–" and cells[k][0] != "–" for k in missing)
    assert all(cells[k][1] == f"{rows[1]['stages'][k]:.3g}" for k in rows[1]["stages"])


def test_bench_command_writes_json(tmp_path):
    out = tmp_path / "k.json"
    proc = subprocess.run([sys.executable, "-m", "lfsf", "bench", "kernels", "--size", "16", "12", "--repeats", "2",
                           "--json", str(out), "--quiet"], capture_output=True, text=True,
                          env={**os.environ, "LFSF_DEVICE": ""})
    assert proc.returncode == 0, proc.stderr
    rows = json.loads(out.read_text())
    assert len(rows) == 5 and all({"kernel", "seconds_median", "gbytes_per_s", "memcpy_gbytes_per_s"} <= set(r)
                                  for r in rows)
    assert "| kernel |" in proc.stdout


def test_bench_peers_rows_without_or_with_the_peers():
    rows = bench.bench_peers((48, 32), "cpu", repeats=1)
    assert [r["method"] for r in rows] == ["lfsf flow-only", "lfsf flow preset", "lfsf scene flow", "opencv DualTVL1",
                                          "skimage TV-L1"]
    for r in rows[:3]:
        assert np.isfinite(r["epe"]) and r["seconds_median"] > 0
    for r in rows[3:]:
        assert r["epe"] is None and "not installed" in r["note"] or np.isfinite(r["epe"])


def test_bench_peers_says_a_missing_peer_is_skipped_and_how_to_install_it(monkeypatch):
    """A peer that is not installed: its progress line says "skipped" (it said "warm-up
    and 1 run"), and its row says how to install it from anywhere (the extra's
    ``pip install -e '.[peers]'`` works only in the checkout)."""
    import sys

    from lfsf import peers

    def no_opencv():
        raise ImportError("No module named 'cv2'")

    monkeypatch.setattr(peers, "_opencv_dual_tvl1", no_opencv)
    monkeypatch.setitem(sys.modules, "skimage.registration", None)  # (its import raises ImportError)
    said = []
    rows = bench.bench_peers((48, 32), "cpu", repeats=1, progress=said.append)
    assert "opencv DualTVL1: skipped, not installed" in said and "skimage TV-L1: skipped, not installed" in said
    assert not any(m.startswith(("opencv", "skimage")) and "run" in m for m in said)
    assert "pip install opencv-contrib-python-headless (or pip install -e '.[peers]'" in rows[3]["note"]
    assert "pip install scikit-image (or" in rows[4]["note"]
    assert all(r["epe"] is None and r["seconds_median"] is None and r["ratio_to_opencv"] is None for r in rows[3:])


def test_bench_peers_checks_the_peers_first_and_a_broken_one_is_its_row(monkeypatch):
    """A peer installed but broken (its import raising another error than ImportError, as
    a NumPy ABI mismatch does) had ended the whole run with a traceback, the lfsf rows
    measured lost; it is now its row, said before any run, and the others are measured.
    A peer that fails in its run is its row too."""
    from lfsf import peers

    def broken():
        raise RuntimeError("module compiled against ABI version 0x1000009")

    def failing(*_a, **_k):
        raise MemoryError("out of memory")

    monkeypatch.setattr(peers, "_opencv_dual_tvl1", broken)
    monkeypatch.setattr(peers, "skimage_tvl1", failing)
    for name in ("skimage", "skimage.registration"):  # (import, installed or not)
        monkeypatch.setitem(sys.modules, name, types.ModuleType(name))
    said = []
    rows = bench.bench_peers((48, 32), "cpu", repeats=1, progress=said.append)
    assert said[1] == "opencv DualTVL1: skipped, failed to import", said
    assert rows[3]["note"] == "failed to import (RuntimeError: module compiled against ABI version 0x1000009)"
    assert rows[4]["note"] == "failed (MemoryError: out of memory)" and rows[4]["epe"] is None
    assert all(np.isfinite(r["epe"]) and r["ratio_to_opencv"] is None for r in rows[:3])
    table = bench.format_rows("peers", rows)
    assert "opencv DualTVL1: failed to import (RuntimeError" in table
    assert max(len(line) for line in table.splitlines()) <= bench.TABLE_WIDTH


def test_bench_rows_say_what_they_were_measured_on_and_the_tables_fit_80_columns(monkeypatch):
    """Every row records the machine (the CPU's model, not only 'x86_64'; the versions;
    the time) for comparing machines; the timed runs are in the row with the warm-up's
    seconds apart; the tables fit a terminal (the pipeline's had 212 characters). At
    17×17, the smallest size, a view with no occluded pixel has occlusion shares of
    nothing, NaN: null in the JSON (their rounding, when they were None, had raised
    TypeError)."""
    from lfsf._files import json_bytes

    rows = bench.bench_pipeline((17, 17), "cpu", repeats=2, settings=(("paper", "paper", {}),))
    (row,) = rows
    assert np.isnan(row["errors"]["occluded"]["f1"]) and '"f1": null' in json_bytes(rows).decode()
    assert len(row["seconds"]) == 2 and row["seconds_median"] == pytest.approx(np.median(row["seconds"]))
    assert len(row["warmup_seconds"]) == 1 and 0 < row["rss_start_mb"] <= row["peak_rss_mb"]
    where = row["machine"]
    assert where["cpu"] == bench.cpu_model() and where["cpus"] == os.cpu_count() and where["device"] == "cpu"
    assert {"python", "warp", "lfsf", "measured_at", "usable_cpus", "cpu_threads"} <= set(where)
    if os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo") as f:
            models = [line.split(":", 1)[1].strip() for line in f if line.startswith("model name")]
        if models:
            assert where["cpu"] == models[0]
    kernels = bench.bench_kernels((24, 16), "cpu", repeats=2, inputs="random")
    assert all(r["machine"]["cpu"] == where["cpu"] and len(r["seconds"]) == 2 for r in kernels)
    for kind, some in (("pipeline", rows), ("kernels", kernels)):
        table = bench.format_rows(kind, some)
        assert max(len(line) for line in table.splitlines()) <= bench.TABLE_WIDTH, table


def test_peak_rss_is_in_megabytes_of_a_million_bytes():
    """``peak_rss_mb`` is what its name says: /proc's kB are 1024 bytes, and its figure
    had been MiB (4.6 % below MB)."""
    if not os.path.exists("/proc/self/status"):
        pytest.skip("no /proc on this system")
    with open("/proc/self/status") as f:
        kb = {line.split(":")[0]: int(line.split()[1]) for line in f if line.startswith(("VmHWM", "VmRSS"))}
    assert bench.peak_rss_mb() == pytest.approx(kb["VmHWM"] * 1024 / 1e6, rel=0.05)
    assert bench.rss_mb() == pytest.approx(kb["VmRSS"] * 1024 / 1e6, rel=0.05)
    assert bench.peak_rss_mb() > kb["VmHWM"] / 1024 * 1.04


def test_peak_rss_is_each_settings_own_where_it_can_be_reset():
    """bench pipeline gave every setting the process's peak so far (the paper setting's)."""
    import numpy as np

    from lfsf import bench

    big = np.ones(64 * 2**20 // 8)          # 64 MB touched
    with_big = bench.peak_rss_mb()
    del big
    if not bench.reset_peak_rss():
        pytest.skip("this system cannot reset the peak resident set")
    assert bench.peak_rss_mb() < with_big - 32


def test_peak_rss_without_proc_or_the_resource_module_is_unknown_not_an_error(monkeypatch):
    """Windows has neither /proc nor :mod:`resource`, which bench imported at the top: every
    ``lfsf bench`` ended in ModuleNotFoundError there. Without them (and off Windows, where
    its own query fails too) the peak is None, and the table and the summary say so."""
    monkeypatch.setattr(bench, "_proc_status_mb", lambda key: None)
    monkeypatch.setitem(sys.modules, "resource", None)   # import resource: ImportError
    if sys.platform != "win32":
        assert bench.peak_rss_mb() is None
    else:
        assert bench.peak_rss_mb() > 10
    row = {"setting": "paper", "device": "cpu", "size": [64, 48], "views": 17, "seconds_median": 1.0,
           "seconds_min": 1.0, "seconds_max": 1.0, "stages": {"iterate": 0.5}, "peak_rss_mb": None}
    assert "| 17 | 1 (1–1) | – |" in bench.format_rows("pipeline", [row])
