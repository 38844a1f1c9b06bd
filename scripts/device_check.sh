#!/usr/bin/env bash
# The CUDA checks of issue 4 in one prepared run, for a session that is lent a GPU
# machine (the `device` tool: a bare machine with Python 3.12, CUDA, NumPy, imageio,
# scikit-image, pytest and pytest-xdist, but no warp-lang, no zstd and no network).
#
# warp-lang (its wheel is 149 MB) is larger than the 64 MiB that one device call may
# carry. So the Warp installed here travels as an xz tarball (about 98 MB) in two
# halves, over two calls while the machine stays warm (30 s after a call; /tmp is kept
# while it is, files written into the checkout are not):
#
#   here:             bash scripts/device_check.sh prepare        # .whl/a/, .whl/b/ (ignored)
#   device call 1:    bash scripts/device_check.sh stash          # carry [".whl/a"]
#   device call 2, at once:
#                     bash scripts/device_check.sh run "$OUT"     # carry [".whl/b"]
#
# The real light fields of ../shared/data (51 MB) travel the same way, in a call of their
# own between those two: `prepare` copies them to .whl/data, and
#
#   device call 1b:   bash scripts/device_check.sh stash-data     # carry [".whl/data"]
#
# keeps them in /tmp/lfsf-data; `run` then adds the step `real` (compare_peers.py
# --real on cuda:0: HCI antinous and the Lytro scene against their bars).
#
# `run` unpacks Warp, puts this tree's lfsf on the path, then writes under OUT:
# nvidia-smi.txt, pytest.txt (every test on cuda:0, 8 processes), kernels.json/.txt
# (`lfsf bench kernels`), pipeline.json/.txt (`lfsf bench pipeline`), demo.txt (`lfsf
# demo` on cuda:0), profile.txt (a `paper` run's stages, GPU activity and host profile),
# real.json/.txt (with the data stashed). Every step took 70 s in the thirtieth session
# (the real data about 60 s more, most of it compiling); give the call a timeout of
# 400 s. LFSF_CHECK_STEPS picks some of the steps (a space-separated list of tests,
# kernels, pipeline, demo, profile, real; all of them when unset).
set -u -o pipefail

mode=${1:-}

case "$mode" in
prepare)
    # Warp is pure Python around its own shared libraries: the package installed here
    # runs on the device's Python 3.12 as it is
    warp_dir=$(python3 -c "import warp, os; print(os.path.dirname(warp.__file__))") || exit 2
    rm -rf .whl && mkdir -p .whl/a .whl/b
    tar -C "$(dirname "$warp_dir")" --exclude='warp/examples' --exclude='warp/tests' --exclude='__pycache__' \
        -cf - warp | xz -T2 -9 > .whl/warp.tar.xz || exit 2
    half=$(( ($(stat -c %s .whl/warp.tar.xz) + 1) / 2 ))
    split -b "$half" -d -a 1 .whl/warp.tar.xz .whl/part.
    mv .whl/part.0 .whl/a/warp.part0
    mv .whl/part.1 .whl/b/warp.part1
    rm .whl/warp.tar.xz
    if [ -d ../shared/data ]; then  # (the real light fields, for `stash-data`)
        mkdir -p .whl/data
        for d in hci-antinous lytro-illum-2067; do
            [ -d "../shared/data/$d" ] && cp -r "../shared/data/$d" .whl/data/ && chmod -R u+w ".whl/data/$d"
        done
    fi
    ls -l .whl/a .whl/b; du -sh .whl/data 2>/dev/null
    ;;
stash-data)
    [ -d .whl/data ] || { echo "error: no .whl/data here: run 'prepare' where ../shared/data is, and carry .whl/data" >&2; exit 2; }
    mkdir -p /tmp/lfsf-data && cp -r .whl/data/* /tmp/lfsf-data/ && du -sh /tmp/lfsf-data/*
    ;;
stash)
    # /tmp stays while the machine is warm; the checkout is replaced at each call
    mkdir -p /tmp/lfsf-warp && cp .whl/a/warp.part0 /tmp/lfsf-warp/ && ls -l /tmp/lfsf-warp && nvidia-smi -L
    ;;
run)
    out=${2:?usage: device_check.sh run OUT_DIR}
    mkdir -p "$out"
    export PYTHONUNBUFFERED=1
    if [ -d /tmp/site/warp ]; then
        export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
    elif ! python3 -c "import warp" 2>/dev/null; then
        [ -f /tmp/lfsf-warp/warp.part0 ] && [ -f .whl/b/warp.part1 ] || {
            echo "error: no Warp here and not both halves of it (/tmp/lfsf-warp/warp.part0 from 'stash' on this" \
                 "machine, .whl/b from carry): the machine went back between the calls? stash again" >&2
            exit 2
        }
        mkdir -p /tmp/site
        cat /tmp/lfsf-warp/warp.part0 .whl/b/warp.part1 \
            | python3 -c "import sys, tarfile; tarfile.open(fileobj=sys.stdin.buffer, mode='r|xz').extractall('/tmp/site')" \
            || exit 2
        export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
    fi
    # lfsf from this tree, no install (pip would want to build): lfsf.kernels is kernels/
    ln -sfn ../kernels lfsf/kernels
    export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
    python3 -c "import lfsf.kernels.tgv, lfsf.cli" || exit 2
    (nvidia-smi; python3 -c "import warp as wp; wp.init(); print(wp.get_cuda_devices())") > "$out/nvidia-smi.txt" 2>&1
    steps=" ${LFSF_CHECK_STEPS:-tests kernels pipeline demo profile real} "
    want() { [[ "$steps" == *" $1 "* ]]; }
    xdist=$(python3 -c "import xdist" 2>/dev/null && echo "-n 8 -p no:benchmark")
    # shellcheck disable=SC2086
    status=0
    if want tests; then
        timeout 150 python3 -m pytest -q -p no:cacheprovider $xdist -k cuda tests 2>&1 | tee "$out/pytest.txt" | tail -5
        status=$(( status | $? ))
    fi
    if want kernels; then
        timeout 90 python3 -m lfsf bench kernels --device cuda:0 --repeats 30 --json "$out/kernels.json" 2>&1 \
            | tee "$out/kernels.txt"
        status=$(( status | $? ))
    fi
    if want pipeline; then
        timeout 120 python3 -m lfsf bench pipeline --device cuda:0 --repeats 7 --json "$out/pipeline.json" 2>&1 \
            | tee "$out/pipeline.txt"
        status=$(( status | $? ))
    fi
    if want demo; then
        timeout 60 python3 -m lfsf demo --device cuda:0 --out /tmp/lfsf-demo 2>&1 | tee "$out/demo.txt"
        status=$(( status | $? ))
    fi
    # where a `paper` run's time goes on the GPU: its stages, the GPU's own activity (CUDA
    # events; a replayed graph counts as one) and the host's Python (cProfile)
    if want profile; then
    timeout 90 python3 - > "$out/profile.txt" 2>&1 <<'PY'
import cProfile, collections, io, pstats, time
import warp as wp
from lfsf import Params, estimate_scene_flow, synth
lf1, lf2, _gt = synth.render_scene("paper", size=(640, 480), grid=9, device="cuda:0")
params = Params.preset("paper")
for _ in range(2):
    estimate_scene_flow(lf1, lf2, params, device="cuda:0")
wp.timing_begin(cuda_filter=wp.TIMING_ALL)
t = time.perf_counter()
sf = estimate_scene_flow(lf1, lf2, params, device="cuda:0")
wall = time.perf_counter() - t
activity = collections.defaultdict(lambda: [0.0, 0])
for r in wp.timing_end():
    activity[r.name][0] += r.elapsed
    activity[r.name][1] += 1
print(f"wall {wall:.3f} s; GPU activity {sum(v[0] for v in activity.values()) / 1000:.3f} s")
print({k: round(v, 3) for k, v in sf.timings.items()})
for name, (ms, count) in sorted(activity.items(), key=lambda kv: -kv[1][0])[:25]:
    print(f"{ms:9.3f} ms {count:6d}  {name}")
profile = cProfile.Profile()
profile.enable()
estimate_scene_flow(lf1, lf2, params, device="cuda:0")
profile.disable()
text = io.StringIO()
pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(30)
pstats.Stats(profile, stream=text).sort_stats("cumulative").print_stats(45)
print(text.getvalue())
PY
        status=$(( status | $? ))
        head -30 "$out/profile.txt"
    fi
    if want real && [ -d /tmp/lfsf-data ]; then
        timeout 240 python3 scripts/compare_peers.py --real --no-synth --methods lfsf --data /tmp/lfsf-data \
            --device cuda:0 --json "$out/real.json" 2>&1 | tee "$out/real.txt" | tail -8
        status=$(( status | $? ))
    fi
    exit "$status"  # (not 0 where a step failed: a step left out is not a failure)
    ;;
*)
    echo "usage: device_check.sh prepare | stash | stash-data | run OUT_DIR" >&2
    exit 2
    ;;
esac
