"""Where an estimate's time goes, kernel by kernel.

Runs :func:`lfsf.estimate_scene_flow` once to compile and warm up, then once timed with
every launch synchronised and timed on its own: the launches of
:func:`lfsf.device.launch_rows`, the recorded ones (:class:`lfsf.device.RecordedRows`)
and the iterations (:class:`lfsf.device.CapturedLoop`, replayed step by step instead of
as a captured graph). Prints a Markdown table of the kernels by total seconds, with their
launches and share of the run, and the estimator's own stages.

    python scripts/profile_kernels.py --scene paper --size 640 480
    python scripts/profile_kernels.py --scene random-3 --size 320 240 --preset fast --json prof.json

The synchronisation adds a little to each launch (about 10 µs on the CPU), so the kernels'
sum runs somewhat above a plain run's time on small images; on CUDA it also keeps launches
from overlapping. What it is for is the order of the kernels and their shares, not the
total. Exit status 2 on a bad scene, size or preset.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path
from lfsf._errors import ArgumentParser  # noqa: E402  (usage errors in one line)
from lfsf._scripts import check_before_runs  # noqa: E402


class KernelTimes:
    """Patch lfsf's launch paths to time every launch by kernel, for as long as the
    ``with`` block runs. ``seconds`` and ``launches`` are keyed by the kernel's name."""

    def __init__(self, device: str):
        self.device = device
        self.seconds: collections.Counter = collections.Counter()
        self.launches: collections.Counter = collections.Counter()

    def _timed(self, name: str, call):
        from lfsf.device import warp

        wp = warp()
        wp.synchronize_device(self.device)
        start = time.perf_counter()
        call()
        wp.synchronize_device(self.device)
        self.seconds[name] += time.perf_counter() - start
        self.launches[name] += 1

    def __enter__(self):
        from lfsf import device

        self._saved = (device.launch_rows, device.RecordedRows.__call__, device.CapturedLoop.run)
        launch_rows, recorded_call, _loop_run = self._saved
        times = self

        def timed_launch_rows(kernel, *args, **kwargs):
            times._timed(_name(kernel), lambda: launch_rows(kernel, *args, **kwargs))

        def timed_recorded_call(recorded):
            times._timed(_name(recorded.launches[0].kernel), lambda: recorded_call(recorded))

        def stepwise_run(loop, n):  # no graph: a captured graph would hide its kernels
            for _ in range(max(0, n)):
                for step in loop.steps:
                    step()

        device.launch_rows = timed_launch_rows
        device.RecordedRows.__call__ = timed_recorded_call
        device.CapturedLoop.run = stepwise_run
        return self

    def __exit__(self, *exc):
        from lfsf import device

        device.launch_rows, device.RecordedRows.__call__, device.CapturedLoop.run = self._saved
        return False


def _name(kernel) -> str:
    """A kernel's name without the factory's prefix (``_tgv_steps__locals__tgv_dual_step``
    → ``tgv_dual_step``)."""
    return kernel.key.split("__locals__")[-1]


def profile(scene: str, size, preset: str, device: str | None = None) -> dict:
    """Render ``scene`` at ``size``, estimate it with ``preset`` (warm-up, then timed) and
    return {"seconds": the timed run's wall time, "stages": its stage timings,
    "kernels": [{"kernel", "seconds", "launches"}] by total seconds, descending}."""
    from lfsf import Params, estimate_scene_flow, synth
    from lfsf.device import resolve_device

    dev = resolve_device(device)
    lf1, lf2, _gt = synth.render_scene(scene, size=tuple(size), device=dev)
    params = Params.preset(preset)
    estimate_scene_flow(lf1, lf2, params, device=dev)  # compile and warm up
    with KernelTimes(dev) as times:
        start = time.perf_counter()
        result = estimate_scene_flow(lf1, lf2, params, device=dev)
        seconds = time.perf_counter() - start
    kernels = [{"kernel": k, "seconds": round(v, 4), "launches": times.launches[k]}
               for k, v in times.seconds.most_common()]
    return {"scene": scene, "size": list(size), "preset": preset, "device": dev, "seconds": round(seconds, 3),
            "stages": {k: round(v, 3) for k, v in result.timings.items()}, "kernels": kernels}


def table(report: dict) -> str:
    total = report["seconds"]
    lines = [f"{report['scene']} at {report['size'][0]}×{report['size'][1]}, preset {report['preset']}, "
             f"{report['device']}: {total:.2f} s with every launch synchronised",
             "", "| kernel | seconds | launches | share of the run |", "|---|---:|---:|---:|"]
    for row in report["kernels"]:
        lines.append(f"| {row['kernel']} | {row['seconds']:.3f} | {row['launches']} | "
                     f"{100 * row['seconds'] / total:.1f} % |")
    summed = sum(r["seconds"] for r in report["kernels"])
    lines.append(f"| (all kernels) | {summed:.3f} | {sum(r['launches'] for r in report['kernels'])} | "
                 f"{100 * summed / total:.1f} % |")
    stages = ", ".join(f"{k} {v:.2f}" for k, v in sorted(report["stages"].items(), key=lambda kv: -kv[1]) if v > 0)
    lines += ["", f"stages (s): {stages}"]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="paper", help="a built-in scene or random-SEED (default paper)")
    p.add_argument("--size", type=int, nargs=2, default=(640, 480), metavar=("W", "H"), help="view size (default 640 480)")
    p.add_argument("--preset", default="paper")
    p.add_argument("--device", default=None, help="cpu or cuda:N (default as lfsf run)")
    p.add_argument("--json", type=Path, default=None, help="also write the report to this JSON file")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from lfsf import Params, synth

    try:
        synth.get_scene(args.scene)
        if min(args.size) < 16:
            raise ValueError(f"--size must be at least 16×16, got {args.size[0]}×{args.size[1]}")
        Params.preset(args.preset)
        check_before_runs(args.size, 9, output=args.json, scored=False)
        report = profile(args.scene, args.size, args.preset, args.device)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(table(report))
    if args.json is not None:
        from lfsf._files import write_json_atomic

        write_json_atomic(args.json, report)
    return 0


if __name__ == "__main__":
    from lfsf._errors import run_script

    sys.exit(run_script(main))
