#!/usr/bin/env bash
# The test suite in fresh virtual environments at the edges of what pyproject.toml allows:
#
#   oldest  Python 3.10 with every core dependency at its lowest allowed version
#           (warp-lang 1.17.0, numpy 1.23.5, imageio 2.31.0, tifffile 2022.8.12,
#           rawpy 0.19.0, tomli 2.0.1), and the dev extra;
#   newest  the newest Python given (default 3.13), with whatever pip resolves today.
#
# Each runs `pytest` from a clone of HEAD with its own, empty Warp kernel cache, so
# every kernel compiles afresh (about 8 minutes on 2 cores). The peers extra is left
# out: its tests skip.
#
#   bash scripts/check_versions.sh [oldest|newest ...]     (default: both)
#
# Environment: PY310, PY_NEWEST (interpreters; default python3.10 and python3.13 on
# PATH), WORK (a scratch folder; default a new one under /tmp). Needs pip to reach an
# index or a wheel folder. Exit status: 0 when every configuration passed, else 1;
# 2 for an unknown configuration or a missing interpreter.
set -uo pipefail

case "${1:-}" in
    -h|--help) sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
esac

repo="$(cd "$(dirname "$0")/.." && pwd)"
work="${WORK:-$(mktemp -d /tmp/lfsf-versions.XXXXXX)}"
configs=("$@")
[ ${#configs[@]} -eq 0 ] && configs=(oldest newest)

failed=0
for config in "${configs[@]}"; do
    case "$config" in
        oldest) python="${PY310:-python3.10}"
                pins=("warp-lang==1.17.0" "numpy==1.23.5" "imageio==2.31.0" "tifffile==2022.8.12" "rawpy==0.19.0"
                      "tomli==2.0.1") ;;
        newest) python="${PY_NEWEST:-python3.13}"
                pins=() ;;
        *) echo "check_versions: unknown configuration '$config' (oldest, newest)" >&2; exit 2 ;;
    esac
    if ! command -v "$python" >/dev/null; then
        echo "check_versions: no interpreter '$python' for '$config'" >&2
        exit 2
    fi
    dir="$work/$config"
    rm -rf "$dir" && mkdir -p "$dir"
    git clone -q "$repo" "$dir/src"
    "$python" -m venv "$dir/venv"
    printf '%s\n' "${pins[@]}" > "$dir/constraints.txt"
    echo "== $config: $("$python" --version), constraints: ${pins[*]:-none}"
    if ! "$dir/venv/bin/pip" install -q -c "$dir/constraints.txt" -e "$dir/src[dev]"; then
        echo "== $config: install failed"
        failed=1
        continue
    fi
    "$dir/venv/bin/pip" list 2>/dev/null | grep -i -E '^(warp-lang|numpy|imageio|tifffile|rawpy) '
    (cd "$dir/src" && WARP_CACHE_PATH="$dir/kernel-cache" "$dir/venv/bin/python" -m pytest -q -p no:cacheprovider \
        > "$dir/pytest.log" 2>&1)
    status=$?
    grep -E '^(FAILED|ERROR) ' "$dir/pytest.log"
    tail -n 1 "$dir/pytest.log"
    echo "== $config: pytest exit status $status (the whole log: $dir/pytest.log)"
    [ "$status" -eq 0 ] || failed=1
done
exit $failed
