"""Benchmarks behind ``lfsf bench kernels|pipeline|peers`` (INTERFACE.md, Benchmarks).

Every figure is the median of repeated runs after a warm-up, with its spread (min, max):
the machine is shared and noisy, so single timings are not quoted. Each benchmark returns
a list of rows (dicts) that the command prints as a table and writes as JSON.

* ``pipeline``: the whole estimator (:func:`lfsf.estimate_scene_flow`) on a synthetic scene,
  per setting (the paper's first), with the per-stage seconds of the median run and the
  process's peak resident memory.
* ``kernels``: the hot kernels on inputs of the paper's setting, as effective bandwidth —
  the bytes each kernel must move (every array it reads once, every array it writes
  once) over its time — next to a plain array copy of the same size on the same device
  (the faster of one copy and, on the CPU, a copy in row bands as the kernels run),
  timed in alternation with the kernel.
* ``peers``: flow-only lfsf, the whole scene flow, OpenCV's DualTVL1 and scikit-image's
  TV-L1 on the same pair, with their end-point errors.
"""

from __future__ import annotations

import math
import os
import platform
import statistics
import sys
import time
from typing import Any, Callable

import numpy as np

from lfsf import device as _device

#: (name, preset, Params overrides) of the pipeline settings; the paper's first.
PIPELINE_SETTINGS = (
    ("paper", "paper", {}),
    ("fast", "fast", {}),
    ("flow only (M=1)", "paper", {"circles": 1, "samples": (1,)}),
)


def _proc_status_mb(key: str) -> float | None:
    """A size of /proc/self/status (``VmHWM``, ``VmRSS``; kB there, 1024 bytes) in MB
    (10⁶ bytes), or None where there is no such file (not Linux)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024 / 1e6
    except OSError:
        pass
    return None


def peak_rss_mb() -> float | None:
    """Peak resident set size of this process since :func:`reset_peak_rss` (where Linux
    allows it to be reset: VmHWM), else since it started (ru_maxrss; on Windows the peak
    working set), in MB of 10⁶ bytes (not MiB: the kernel's kB are 1024 bytes); None where
    the system tells none."""
    peak = _proc_status_mb("VmHWM")
    if peak is not None:
        return peak
    try:
        import resource  # (POSIX only)
    except ImportError:
        return _windows_peak_mb()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss * 1024 / 1e6 if sys.platform != "darwin" else rss / 1e6


def _windows_peak_mb() -> float | None:
    """The process's peak working set (Windows' ``GetProcessMemoryInfo``) in MB, or None."""
    try:
        import ctypes
        from ctypes import wintypes

        class Counters(ctypes.Structure):  # PROCESS_MEMORY_COUNTERS
            _fields_ = [("cb", wintypes.DWORD), ("PageFaultCount", wintypes.DWORD)] + [
                (name, ctypes.c_size_t) for name in (
                    "PeakWorkingSetSize", "WorkingSetSize", "QuotaPeakPagedPoolUsage", "QuotaPagedPoolUsage",
                    "QuotaPeakNonPagedPoolUsage", "QuotaNonPagedPoolUsage", "PagefileUsage", "PeakPagefileUsage")]

        counters = Counters()
        counters.cb = ctypes.sizeof(Counters)
        kernel32 = ctypes.WinDLL("kernel32")  # type: ignore[attr-defined]
        kernel32.GetCurrentProcess.restype = wintypes.HANDLE
        query = kernel32.K32GetProcessMemoryInfo  # (psapi's GetProcessMemoryInfo, in kernel32 since Windows 7)
        query.argtypes = [wintypes.HANDLE, ctypes.POINTER(Counters), wintypes.DWORD]
        if not query(kernel32.GetCurrentProcess(), ctypes.byref(counters), counters.cb):
            return None
        return counters.PeakWorkingSetSize / 1e6
    except (OSError, AttributeError, ValueError):
        return None


def _rounded_mb(mb: float | None) -> float | None:
    """A size in MB to a tenth (None stays None: a system that tells none)."""
    return None if mb is None else round(mb, 1)


def mb_text(mb: float | None) -> str:
    """A size in MB as the tables print it ("–" where the system tells none)."""
    return "–" if mb is None else f"{mb:.0f}"


def rss_mb() -> float | None:
    """This process's resident set size now, in MB (None where it cannot be read)."""
    return _proc_status_mb("VmRSS")


def cpu_model() -> str:
    """The processor's model name (Linux's /proc/cpuinfo, e.g. "AMD EPYC 9454 48-Core
    Processor"), else what :mod:`platform` says (often the architecture alone)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_record(device: str | None = None) -> dict[str, Any]:
    """What every row records of the machine it was measured on, for comparing machines:
    the CPU model, its logical CPUs (``cpus``) and those this process may use
    (``usable_cpus``), the threads that CPU launches run on, ``device`` and its name
    (a GPU's model), the Python, Warp and lfsf versions, and when (``measured_at``, UTC)."""
    import datetime

    from lfsf import __version__

    record: dict[str, Any] = {"cpu": cpu_model(), "cpus": os.cpu_count(), "usable_cpus": _device.usable_cpus(),
                              "cpu_threads": _device.cpu_threads(), "python": platform.python_version(),
                              "lfsf": __version__}
    if device is not None:
        wp = _device.warp()
        record.update(device=device, device_name=str(wp.get_device(device).name), warp=wp.config.version)
    record["measured_at"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    return record


def reset_peak_rss() -> bool:
    """Start :func:`peak_rss_mb` again from the present resident set (Linux ≥ 4.0: 5 to
    /proc/self/clear_refs); False where it cannot, and the peak is then the process's."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def summarise(seconds: list[float]) -> dict:
    """Median and spread of repeated timings, and the timings themselves (``seconds``: a
    kernel's are its samples, each the mean of ``launches_per_sample`` launches)."""
    return {
        "seconds_median": statistics.median(seconds),
        "seconds_min": min(seconds),
        "seconds_max": max(seconds),
        "repeats": len(seconds),
        "seconds": [float(x) for x in seconds],
    }


def time_repeated(fn: Callable[[], object], repeats: int, warmup: int = 1, sync: Callable[[], None] | None = None,
                  warmup_seconds: list[float] | None = None):
    """Run ``fn`` ``warmup`` times untimed, then ``repeats`` times timed; returns the
    list of seconds and the last result. ``sync`` (e.g. a device synchronisation) runs
    before each clock reading. The warm-ups' seconds (a first run's kernel compile, on a
    cold cache, among them) are appended to ``warmup_seconds`` where it is given."""
    sync = sync or (lambda: None)
    result = None
    for _ in range(warmup):
        t0 = time.perf_counter()
        result = fn()
        sync()
        if warmup_seconds is not None:
            warmup_seconds.append(time.perf_counter() - t0)
    sync()
    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        sync()
        seconds.append(time.perf_counter() - t0)
    return seconds, result


# --- pipeline ------------------------------------------------------------------------------

def bench_pipeline(size=(640, 480), device: str | None = None, repeats: int = 3, scene: str = "paper",
                   settings=PIPELINE_SETTINGS, progress: Callable[[str], None] | None = None) -> list[dict]:
    """Rows of the whole estimator per setting: seconds (median, spread) of the timed
    runs, per-stage seconds of the median run, peak RSS, and the errors against the
    ground truth. Each setting runs once untimed first (``warmup_seconds``: a cold
    kernel cache's compile falls there, as does its memory, in ``peak_rss_mb``); the
    scene's rendering is not timed. ``rss_start_mb`` is the resident set when the
    setting began (the modules imported, the scene rendered, what earlier settings
    left), which its peak includes."""
    from lfsf import synth
    from lfsf.estimate import estimate_scene_flow
    from lfsf.evaluate import SYNTH_BORDER, evaluate
    from lfsf.params import Params

    say = progress or (lambda _m: None)
    dev = _device.resolve_device(device)
    width, height = size
    say(f"rendering '{scene}' at {width}×{height}")
    lf1, lf2, gt = synth.render_scene(scene, size=(width, height), grid=9, device=dev)
    rows = []
    machine_info = machine_record(dev)
    for name, preset, overrides in settings:
        params = Params.preset(preset).replace(**overrides)
        runs = []
        warmups: list[float] = []

        def once():
            sf = estimate_scene_flow(lf1, lf2, params, device=dev)
            runs.append(sf)
            return sf

        say(f"{name}: warm-up and {repeats} run{'s' if repeats != 1 else ''}")
        # each setting's own peak (it was the process's so far: the paper setting's for all)
        own_peak = reset_peak_rss()
        start = rss_mb()
        seconds, _ = time_repeated(once, repeats, warmup=1, warmup_seconds=warmups)
        timed = runs[1:]
        order = np.argsort(seconds)
        median_run = timed[int(order[len(seconds) // 2])]
        # the stages of the median, as seconds_median: with an even count the mean of the
        # two middle runs (they were the slower one's alone)
        middle = [timed[int(k)] for k in order[(len(seconds) - 1) // 2: len(seconds) // 2 + 1]]
        stages = {k: float(np.mean([run.timings.get(k, 0.0) for run in middle])) for k in median_run.timings}
        # (the SceneFlow itself: a flow-only setting's δ1, δ2 are zeros, not estimates, and unscored)
        errors = evaluate(median_run, gt, border=SYNTH_BORDER)
        phis, _radius = params.sample_offsets(lf1.grid)
        rows.append({
            "setting": name,
            "device": dev,
            "size": [width, height],
            "views": len(phis),
            **summarise(seconds),
            "warmup_seconds": warmups,
            "stages": {k: round(v, 4) for k, v in stages.items()},
            "peak_rss_mb": _rounded_mb(peak_rss_mb()),
            "peak_rss_scope": "setting" if own_peak else "process",
            "rss_start_mb": _rounded_mb(start),
            "errors": {k: {m: _rounded(x) for m, x in v.items()} for k, v in errors.items()},
            "machine": machine_info,
        })
    return rows


# --- kernels -------------------------------------------------------------------------------

def _copies(nbytes: int, dev: str, src=None, dst=None) -> dict[str, Callable[[], None]]:
    """Plain device array copies of ``nbytes`` bytes (read once, written once), by how
    they copy: one ``wp.copy``, and on the CPU, where the kernels run in row bands on
    :func:`lfsf.device.cpu_threads` threads, also one ``wp.copy`` per band from the same
    thread pool. The faster of them is the reference, the device's copy bandwidth
    however it is reached: on this project's 2-core machine the banded copy ran at up
    to 55 GB/s (read + write counted) where one ``wp.copy`` ran at 30–40. ``src`` and
    ``dst``: the float arrays to copy between (default: new ones of ``nbytes``)."""
    wp = _device.warp()
    src = wp.zeros(max(1, nbytes // 4), dtype=float, device=dev) if src is None else src
    n = src.size
    dst = wp.empty(n, dtype=float, device=dev) if dst is None else dst
    copies = {"wp.copy": lambda: wp.copy(dst, src)}
    threads = 1 if wp.get_device(dev).is_cuda else _device.cpu_threads()
    if threads > 1 and n >= threads:
        bands = _device.row_bands(n, threads)

        def banded():
            pool = _device.thread_pool()
            for f in [pool.submit(wp.copy, dst, src, a, a, b - a) for a, b in bands]:
                f.result()

        copies[f"wp.copy in {len(bands)} bands"] = banded
    return copies


#: What the hot kernels run on (:func:`kernel_cases`): "scene", the paper's setting on a
#: rendered scene at its ground truth, as the last warp of a run sees it; "random", random
#: views and unknowns, which make every pixel look hidden to the data term's tests.
KERNEL_INPUTS = ("scene", "random")


def _scene_solver(size, dev: str, scene: str = "paper", params=None):
    """A finest-level solver (:class:`lfsf.solver.LevelSolver`) of the `paper` preset on
    ``scene`` rendered at ``size`` (9×9 views), linearised once at the ground truth: the
    sample stacks (texture parts, contrast normalised, as the estimator makes them), the
    view z-buffers, the hidden mask and the coefficients are those of a run's last warp,
    so the data term's tests and lookups go as they do there (``params``: other settings
    than the preset's). Returns (solver, t1 views as a (81, h, w) array)."""
    from lfsf import synth
    from lfsf.estimate import _normalise_contrast, _structure_texture, data_weights, sample_views
    from lfsf.params import Params
    from lfsf.solver import LevelSolver

    wp = _device.warp()
    width, height = size
    params = Params.preset("paper") if params is None else params
    lf1, lf2, gt = synth.render_scene(scene, size=(width, height), grid=9, device=dev)
    phis, _radius = params.sample_offsets((9, 9))
    n = len(phis)
    weights = data_weights(params, n)
    wp_phis = wp.array(phis, dtype=wp.vec2, device=dev)
    both = wp.empty((2 * n, height, width), dtype=float, device=dev)
    for t, lf in enumerate((lf1, lf2)):
        views = wp.array(np.ascontiguousarray(lf.grey().views.reshape(81, height, width)), dtype=float, device=dev)
        sample_views(views, 9, 9, wp_phis, both[t * n:(t + 1) * n], dev)
        if t == 0:
            views1 = views
    centres = wp.clone(both[0]), wp.clone(both[n])  # (before the contrast is normalised: in place)
    texture = _normalise_contrast(_structure_texture(both, params, dev), params, dev)
    solver = LevelSolver(wp.clone(texture[:n]), wp.clone(texture[n:]), *centres, wp_phis,
                         wp.array(weights, dtype=wp.vec3, device=dev), params, dev)
    solver.set_state(np.stack([gt["disp1"], gt["disp2"], gt["u"], gt["v"]], -1).astype(np.float32))
    solver.linearise()
    return solver, views1


def kernel_cases(size, dev: str, inputs: str = "scene") -> list[tuple[str, Callable[[], None], int]]:
    """(name, launch, bytes it must move) of the hot kernels in the paper's setting (17
    samples on a 9×9 grid of views of ``size``). ``inputs`` (:data:`KERNEL_INPUTS`):
    "scene" (default) gives the sampling and the data-term kernels the arrays of a
    rendered scene's last warp (:func:`_scene_solver`); "random" gives them random
    views and unknowns, a worst case (every pixel takes the data term's occlusion path
    and the lookups scatter). The TGV steps take random values either way: their
    branches are projections that every pixel runs."""
    from lfsf.kernels import data_groups, data_term, tgv
    from lfsf.params import Params

    if inputs not in KERNEL_INPUTS:
        raise ValueError(f"inputs must be one of {', '.join(KERNEL_INPUTS)}, got {inputs!r}")

    from lfsf.estimate import load_kernels
    from lfsf.kernels import render

    wp = _device.warp()
    load_kernels(dev, extra=[render])  # (the scene's renderer and the estimator's, several at once)
    width, height = size
    phis, _radius = Params.preset("paper").sample_offsets((9, 9))
    h, w, s = height, width, len(phis)
    rng = np.random.default_rng(0)
    f = 4  # bytes per float (and per flag word)

    def arr(a, dtype):
        return wp.array(np.ascontiguousarray(a, np.float32), dtype=dtype, device=dev)

    def launch(kernel, inputs, outputs, dim=(h, w)):
        # as the solver launches its iterations: recorded once, replayed (no per-launch
        # argument packing, which costs ~85 µs a launch for the generic kernels)
        recorded = _device.RecordedRows(kernel, dim, inputs=inputs, outputs=outputs, device=dev)
        recorded.arrays = (inputs, outputs)  # alive while the recorded launch is (not every Warp keeps them)
        return recorded

    from lfsf.estimate import sampling_launch
    from lfsf.solver import dual_data_launch, lane_storage

    wp_phis = arr(phis, wp.vec2)
    span, per_row = _device.row_span(dev, w)
    lanes = data_term.data_lanes(dev)
    coefficients, coefficient_columns = data_groups.coefficients_kernel(w, lanes)
    sampled = wp.empty((s, h, w), dtype=float, device=dev)
    flag_words = data_term.pixel_flag_words(s)  # the row flags' words a pixel (three rows)
    if inputs == "scene":
        solver, views = _scene_solver(size, dev)
    else:
        weights = arr(np.tile([10.0 / s, 10.0 / s, 30.0 / s], (s, 1)), wp.vec3)
        views = arr(rng.random((81, h, w)), float)
        stack1 = arr(rng.random((s, h, w)), float)
        stack2 = arr(rng.random((s, h, w)), float)
        x_hat = np.zeros((h, w, 4), np.float32)
        x_hat[..., :2] = rng.uniform(-1, 1, (h, w, 1))
        x_hat[..., 2:] = rng.uniform(-2, 2, (h, w, 2))
        x_hat = arr(x_hat, wp.vec4)
        zeros = arr(np.zeros((h, w)), float)
        # view z-buffers (the default, Params.visibility): a nearer point somewhere in each view
        zbuf1 = arr(rng.uniform(-3, 1, (s, h, w)), float)
        zbuf2 = arr(rng.uniform(-3, 1, (s, h, w)), float)
        # the data term's lane storage, as the solver allocates it

        coef_store, coef = lane_storage(h, w, s, data_term.COEFFICIENTS, lanes, dev)
        flags_store, flags = lane_storage(h, w, 1, flag_words, lanes, dev, flags=True)
        flags_store.zero_()
        q_store, q = lane_storage(h, w, s, data_term.DUALS, lanes, dev)
        grad_j2_store, grad_j2 = lane_storage(h, w, 1, 2, lanes, dev)
        grad_j2_store.zero_()
        coef_store.zero_()  # (uninitialised where the lanes fill the rows; data_coefficients writes them too)
        q_store.zero_()
        colsum = wp.empty((h, w), dtype=wp.vec4, device=dev)

    def v4(scale=1.0):
        return arr(scale * rng.standard_normal((h, w, 4)), wp.vec4)

    def tensor():
        t = rng.uniform(0.1, 1.0, (h, w, 3))
        t[..., 1] = 0.0
        return arr(t, wp.vec3)

    t1, t2, t3 = tensor(), tensor(), tensor()
    # Γ's entries per unknown, as the solver expands them for the TGV steps
    gammas = [wp.empty((h, w), dtype=wp.vec4, device=dev) for _ in range(3)]
    _device.launch_rows(tgv.expand_tensor, dim=(h, w), inputs=[t1, t2, t3], outputs=gammas, device=dev)
    data_grad = v4()
    x_bar, w0_bar, w1_bar = v4(), v4(), v4()
    y0, y1, z00, z01, z10, z11 = (v4(0.1) for _ in range(6))
    x, w0, w1 = v4(), v4(), v4()
    tau = [arr(rng.uniform(0.05, 0.5, (h, w, 4)), wp.vec4) for _ in range(3)]
    sigma_y = arr(rng.uniform(0.05, 0.5, (h, w, 4)), wp.vec4)
    if inputs == "scene":
        p = solver.params
        coef_inputs = [solver.samples1, solver.samples2, solver.phis, solver.weights, solver.x_hat, p.occlusion_ratio,
                       solver.hidden2, solver.view_zbuf1, solver.view_zbuf2, solver.view_margin(),
                       int(solver.view_zbuf1.shape[0] > 1), solver.lanes, int(p.cubic)]
        coef_outputs = [solver.coef_store, solver.flags_store, solver.grad_j2_store, solver.data_colsum,
                        solver.q_store]
        data_step, dual_columns, (d_coef, d_flags, d_grad_j2, d_q), last = dual_data_launch(
            lanes, dev, w, (solver.coef_store, solver.coef), (solver.flags_store, solver.flags),
            (solver.grad_j2_store, solver.grad_j2), (solver.q_store, solver.q))
        dual_inputs = [d_coef, d_flags, solver.weights, d_grad_j2, solver.x_bar, solver.x_hat, p.eps,
                       p.step_ratio, last]
        dual_outputs = [d_q, solver.data_grad]
    else:
        coef_inputs = [stack1, stack2, wp_phis, weights, x_hat, 0.7, zeros, zbuf1, zbuf2, 0.25, 1, lanes,
                       int(Params().cubic)]
        coef_outputs = [coef_store, flags_store, grad_j2_store, colsum, q_store]
        data_step, dual_columns, (d_coef, d_flags, d_grad_j2, d_q), last = dual_data_launch(
            lanes, dev, w, (coef_store, coef), (flags_store, flags), (grad_j2_store, grad_j2), (q_store, q))
        dual_inputs = [d_coef, d_flags, weights, d_grad_j2, x_bar, x_hat, 1e-6, 1.0, last]
        dual_outputs = [d_q, data_grad]
    sample_kernel, sample_dim, sample_inputs = sampling_launch(views, 9, 9, wp_phis, sampled, dev)
    cases = [
        # reads 4 neighbouring views per sample, writes the sample
        ("sample_subaperture", launch(sample_kernel, sample_inputs, [sampled], dim=sample_dim),
         f * h * w * s * 5),
        # reads both sample stacks, x̂, the hidden mask and a value of each view z-buffer per sample; writes
        # 7 coefficients per sample, the row flags (3 words per 31 samples), ∇J2 (2) and the column sums;
        # reads and writes q (the duals of rows left out are zeroed)
        ("data_coefficients", launch(coefficients, coef_inputs, coef_outputs, dim=(h, coefficient_columns)),
         f * h * w * (2 * s + 4 + 1 + 2 * s + data_term.COEFFICIENTS * s + flag_words + 2 + 4 + 6 * s)),
        # reads the coefficients, the row flags, ∇J2 (2), x̄, x̂ and q; writes q and Kᵀq (the S weights stay
        # in cache)
        ("dual_data_step", launch(data_step, dual_inputs, dual_outputs, dim=(h, dual_columns)),
         f * h * w * (data_term.COEFFICIENTS * s + flag_words + 2 + 4 + 4 + 3 * s + 3 * s + 4)),
        # reads x̄, w̄ (12), the three tensors (9: it reads them as Γ's entries per unknown, 12, but is
        # credited with the 9 it must move), σ_y (4) and the six duals (24); writes the duals (24)
        ("tgv_dual_step", launch(tgv.tgv_kernels(dev)[0], [x_bar, w0_bar, w1_bar, *gammas, sigma_y, 0.25, 2.0, 0.5,
                                                     span], [y0, y1, z00, z01, z10, z11], dim=(h, per_row)),
         f * h * w * (12 + 9 + 4 + 24 + 24)),
        # reads Kᵀq (4), the duals (24), the tensors (9, as above), τ (12), x and w (12); writes x, w and their
        # bars (24)
        ("tgv_primal_step", launch(tgv.tgv_kernels(dev)[1],
                                   [data_grad, y0, y1, z00, z01, z10, z11, *gammas, tau[0], tau[1], tau[2],
                                    data_grad.dtype(2.0), 0.5, span], [x, w0, w1, x_bar, w0_bar, w1_bar],
                                   dim=(h, per_row)),
         f * h * w * (4 + 24 + 9 + 12 + 12 + 24)),
    ]
    return cases


#: A timed kernel sample lasts at least this long: shorter launches are repeated within it
#: (at most :data:`MAX_BATCH` times) and the sample is their mean.
MIN_SAMPLE_SECONDS = 2e-3
MAX_BATCH = 1000


def bench_kernels(size=(640, 480), device: str | None = None, repeats: int = 20,
                  progress: Callable[[str], None] | None = None, inputs: str = "scene") -> list[dict]:
    """Rows per hot kernel: seconds per launch (median, spread), effective GB/s and the
    plain-copy GB/s of the same byte count on the same device, and their ratio, on the
    ``inputs`` of :func:`kernel_cases` (a rendered scene's, or random ones). The
    kernel and the copies (:func:`_copies`) are timed in alternation, one sample of each
    per round, so that the machine's changes of speed (up to 1.5× within minutes on
    this shared one) fall on both sides of the ratio. A sample is one launch, or the mean
    of as many as fill :data:`MIN_SAMPLE_SECONDS` where one is shorter (``launches_per_sample``;
    a GPU's launch at 640×480 takes microseconds, about what reading the clock and
    synchronising cost)."""
    wp = _device.warp()
    say = progress or (lambda _m: None)
    dev = _device.resolve_device(device)

    def timed(fn, times=1):
        t0 = time.perf_counter()
        for _ in range(times):
            fn()
        wp.synchronize_device(dev)
        return (time.perf_counter() - t0) / times

    rows = []
    machine_info = machine_record(dev)
    if inputs == "scene":
        say(f"rendering the paper scene at {size[0]}×{size[1]} for the kernels' inputs")
    for name, run, nbytes in kernel_cases(size, dev, inputs):
        copies = _copies(nbytes // 2, dev)  # a copy of nbytes/2 reads and writes nbytes in all
        steps = {name: run, **copies}
        for fn in steps.values():  # warm-up
            for _ in range(2):
                fn()
        wp.synchronize_device(dev)
        # launches per timed sample: enough for MIN_SAMPLE_SECONDS, so that a short launch
        # (microseconds on a GPU) is timed for itself rather than for the clock's reading
        # and the synchronisation; a sample's time is their mean
        times = {k: max(1, min(MAX_BATCH, math.ceil(MIN_SAMPLE_SECONDS / max(timed(fn), 1e-9))))
                 for k, fn in steps.items()}
        each = f" (the mean of {times[name]} launches)" if times[name] > 1 else ""
        say(f"{name}: {repeats} sample{'s' if repeats != 1 else ''}{each}, each followed by the copies")
        seconds: dict[str, list[float]] = {k: [] for k in steps}
        for _ in range(repeats):
            for k, fn in steps.items():
                seconds[k].append(timed(fn, times[k]))
        how = min(copies, key=lambda k: statistics.median(seconds[k]))
        gbs = nbytes / statistics.median(seconds[name]) / 1e9
        copy_gbs = nbytes / statistics.median(seconds[how]) / 1e9
        rows.append({
            "kernel": name,
            "device": dev,
            "size": list(size),
            "inputs": inputs,
            "bytes": int(nbytes),
            **summarise(seconds[name]),
            "gbytes_per_s": round(gbs, 3),
            "memcpy_gbytes_per_s": round(copy_gbs, 3),
            "memcpy": how,
            "fraction_of_memcpy": round(gbs / copy_gbs, 3),
            "launches_per_sample": times[name],
            "machine": machine_info,
        })
    return rows


# --- peers ---------------------------------------------------------------------------------

def _rounded(value):
    """An error figure for the JSON rows: counts (pixels, marked_px) whole, as ``lfsf eval
    --json`` writes them, the rest to 5 decimals (NaN, an occlusion share of nothing,
    stays NaN: null in the JSON)."""
    if isinstance(value, (int, np.integer)):
        return int(value)
    return round(float(value), 5)


def bench_peers(size=(640, 480), device: str | None = None, repeats: int = 3, scene: str = "paper",
                progress: Callable[[str], None] | None = None) -> list[dict]:
    """Rows per method on the same synthetic pair: seconds (median, spread) and the flow
    end-point error over valid pixels (8-px border), and the median's ratio to OpenCV's
    (``ratio_to_opencv``). Peers are checked before any run: one that is not installed
    gets a row saying so and what to install (:data:`lfsf.peers.PEER_PACKAGES`), one whose import
    or run fails another way a row saying how, and the others are measured still."""
    from lfsf import peers, synth
    from lfsf.estimate import estimate_scene_flow
    from lfsf.evaluate import SYNTH_BORDER, evaluate
    from lfsf.params import Params

    say = progress or (lambda _m: None)
    dev = _device.resolve_device(device)
    width, height = size
    say(f"rendering '{scene}' at {width}×{height}")
    lf1, lf2, gt = synth.render_scene(scene, size=(width, height), grid=9, device=dev)
    c1, c2 = lf1.grey().centre, lf2.grey().centre

    def lfsf_run(params):
        sf = estimate_scene_flow(lf1, lf2, params, device=dev)
        return sf.u, sf.v

    methods = [
        ("lfsf flow-only", lambda: lfsf_run(Params.preset("paper").replace(circles=1, samples=(1,)))),
        # the `flow` preset: 5 warps of 20 iterations, steps balanced towards the duals
        ("lfsf flow preset", lambda: lfsf_run(Params.preset("flow"))),
        ("lfsf scene flow", lambda: lfsf_run(Params.preset("paper"))),
        ("opencv DualTVL1", lambda: peers.opencv_tvl1(c1, c2)),
        ("skimage TV-L1", lambda: peers.skimage_tvl1(c1, c2)),
    ]
    def unusable(name: str) -> tuple[str, str] | None:
        # a peer's import, tried before any run (lfsf's runs take minutes at 640×480): why it
        # cannot run (in short, and in full), or None. Not only ImportError: an installed peer
        # whose import fails otherwise (a NumPy ABI mismatch raises other errors) has its row too
        try:
            if name.startswith("opencv"):
                peers._opencv_dual_tvl1()
            elif name.startswith("skimage"):
                import skimage.registration  # noqa: F401
        except ImportError as exc:
            return "not installed", (f"not installed ({exc}); pip install {peers.PEER_PACKAGES[name]} "
                                     f"{peers.PEERS_EXTRA_HINT}")
        except Exception as exc:  # noqa: BLE001 (any failure of a peer's import is that peer's row)
            return "failed to import", f"failed to import ({type(exc).__name__}: {exc})"
        return None

    machine_info = machine_record(dev)
    problems = {name: unusable(name) for name, _fn in methods if not name.startswith("lfsf")}
    for name, problem in problems.items():
        if problem is not None:
            say(f"{name}: skipped, {problem[0]}")
    rows: list[dict[str, Any]] = []
    for name, fn in methods:
        problem = problems.get(name)
        if problem is not None:
            rows.append({"method": name, "epe": None, "seconds_median": None, "note": problem[1]})
            continue
        say(f"{name}: warm-up and {repeats} run{'s' if repeats != 1 else ''}")
        warmups: list[float] = []
        try:
            seconds, (u, v) = time_repeated(fn, repeats, warmup=1, warmup_seconds=warmups)
        except Exception as exc:  # a peer's failure is its row; lfsf's own is an error
            if name.startswith("lfsf"):
                raise
            rows.append({"method": name, "epe": None, "seconds_median": None,
                         "note": f"failed ({type(exc).__name__}: {exc})"})
            continue
        epe = evaluate({"u": u, "v": v}, gt, border=SYNTH_BORDER)["flow"]["epe"]
        rows.append({"method": name, "device": dev if name.startswith("lfsf") else "cpu", "size": [width, height],
                     "epe": round(float(epe), 5), **summarise(seconds), "warmup_seconds": warmups})
    # each method's median time over OpenCV's, measured in this run
    opencv = next((r["seconds_median"] for r in rows if r["method"] == "opencv DualTVL1"), None)
    for r in rows:
        r["ratio_to_opencv"] = (None if opencv is None or r["seconds_median"] is None
                                else round(r["seconds_median"] / opencv, 4))
        r["machine"] = machine_info
    return rows


# --- table ---------------------------------------------------------------------------------

#: What the kernels table's columns mean (printed under it).
KERNELS_KEY = ("GB/s: the bytes the kernel must read and write at least (its inputs and outputs once), over "
               "its median time; copy GB/s: a plain copy's, read and write counted alike, timed in alternation "
               "with the kernel (the faster of one wp.copy and a copy in row bands; at small sizes a copy runs "
               "from the caches, so compare fractions at one size); fraction: the first over the second (the "
               "target is 0.5).")


#: The widest line of the tables and their notes: a terminal's width.
TABLE_WIDTH = 80


def _wrapped(text: str) -> list[str]:
    """``text`` in lines of at most :data:`TABLE_WIDTH` characters."""
    import textwrap

    return textwrap.wrap(text, TABLE_WIDTH)


def format_rows(kind: str, rows: list[dict]) -> str:
    """Markdown tables of benchmark rows, each line at most :data:`TABLE_WIDTH` wide
    (the pipeline's stages a table of their own, a column per setting; notes under the
    table, not in its cells)."""
    def sec(r, unit: float = 1.0):
        """Median (min–max) of a row's times, in seconds over ``unit`` (1e-3: ms)."""
        if r.get("seconds_median") is None:
            return "–"
        return f"{r['seconds_median'] / unit:.4g} ({r['seconds_min'] / unit:.4g}–{r['seconds_max'] / unit:.4g})"

    if kind == "pipeline":
        lines = ["| setting | device | size | views | seconds median (min–max) | peak RSS MB |",
                 "|---|---|---|---|---|---|"]
        for r in rows:
            lines.append(f"| {r['setting']} | {r['device']} | {r['size'][0]}×{r['size'][1]} | {r['views']} | {sec(r)} | "
                         f"{mb_text(r['peak_rss_mb'])} |")
        # the stages, slowest first: seconds of each setting's median run ('–' where a setting has no such stage)
        stages = sorted({k for r in rows for k in r["stages"]}, key=lambda k: -max(r["stages"].get(k, 0) for r in rows))
        lines += ["", "| stage, seconds | " + " | ".join(r["setting"] for r in rows) + " |",
                  "|---|" + "---|" * len(rows)]
        for k in stages:
            lines.append(f"| {k} | " + " | ".join(f"{r['stages'][k]:.3g}" if k in r["stages"] else "–" for r in rows)
                         + " |")
        warm = ", ".join(f"{r['setting']} {sum(r.get('warmup_seconds', [])):.3g} s" for r in rows)
        own = all(r.get("peak_rss_scope") == "setting" for r in rows)
        lines += [""] + _wrapped(f"Not timed: the scene's rendering and each setting's warm-up run ({warm}; a cold "
                                 "kernel cache's compile falls there). Peak RSS: "
                                 + ("each setting's own, from the resident set at its start (the modules and the "
                                    "scene)." if own else "the process's so far (this system cannot reset it between "
                                    "settings)."))
        return "\n".join(lines)
    if kind == "kernels":
        lines = ["| kernel | ms a launch, median (min–max) | GB/s | copy GB/s | fraction |", "|---|---|---|---|---|"]
        for r in rows:
            lines.append(f"| {r['kernel']} | {sec(r, 1e-3)} | {r['gbytes_per_s']:.2f} | {r['memcpy_gbytes_per_s']:.2f} | "
                         f"{r['fraction_of_memcpy']:.2f} |")
        copies = sorted({r.get("memcpy", "wp.copy") for r in rows})
        lines += [""] + _wrapped(KERNELS_KEY + f" Device {rows[0]['device'] if rows else '–'}; the copy: "
                                 + ", ".join(copies) + ".")
        return "\n".join(lines)
    lines = ["| method | seconds median (min–max) | × OpenCV | flow EPE |", "|---|---|---|---|"]
    notes = []
    for r in rows:
        epe = "–" if r.get("epe") is None else f"{r['epe']:.4f}"
        ratio = "–" if r.get("ratio_to_opencv") is None else f"{r['ratio_to_opencv']:.3g}"
        lines.append(f"| {r['method']} | {sec(r)} | {ratio} | {epe} |")
        if r.get("note"):
            notes.append(f"{r['method']}: {r['note']}")
    if notes:
        lines.append("")
        for note in notes:
            lines += _wrapped(note)
    return "\n".join(lines)
