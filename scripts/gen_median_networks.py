"""Generate ``kernels/median_networks.py``: branch-free selection networks for the median
of 9, 25 and 49 values (the 3×3, 5×5 and 7×7 windows of the flow's median filter), and
the sorted-column networks that take the plain median of two neighbouring windows at once.

Each network is Batcher's odd–even merge sort for the next power of two, with the extra
wires padded by −∞ and +∞ in equal numbers (so the median stays the middle wire), the
comparators whose outcome the padding decides removed (they become relabellings), and
then pruned backwards to the comparators that feed the middle wire; a comparator whose
min (or max) output is unused keeps only the other. What is left is straight-line
min/max code without branches: 46, 212 and 614 operations for 9, 25 and 49 values,
against the data-dependent branches of a selection algorithm, which noise in the flow
makes the CPU mispredict. The min and max are single comparisons
(:func:`lfsf.kernels.common.at_most`, ``at_least``), not ``wp.min``/``wp.max``, whose IEEE
fmin/fmax handling of NaN costs more on the CPU.

*The plain median (every pixel of the window takes part) from sorted columns.* Each
column of a window, its 2r+1 rows, is sorted once (a sorting network, 3, 9 and 16
comparators) and serves the 2r+1 windows of its row that hold it. The windows of the
pixels (i, j) and (i, j+1) share the 2r columns j − r + 1 … j + r; of those columns'
(2r+1)·2r values only the 2r + 2 ranks n//2 − (2r+1) … n//2 (0-based, n = (2r+1)²) can be
either window's median, whatever its own last column holds. The network that finds them
is Batcher's sort with the comparators inside a column left out (the columns come
sorted, one to a block of the next power of two wires, padded by ±∞ as
:data:`PAIR_LAYOUTS` says: the layout with the fewest comparators after pruning, found
by trying every placement), pruned to those ranks. Then each window's median is the
(2r+2)-th smallest of those 2r + 2 values and its own sorted column E, that is
min(C[k], max(C[k−1], E[0]), …, max(C[k−2r−1], E[2r])) with C the shared ranks: 10,
88 and 324 operations for the pair's shared ranks at radius 1, 2 and 3, and 2·(2r+1) a
window, against 46, 212 and 614 a window for the networks above.

    python scripts/gen_median_networks.py          # rewrite kernels/median_networks.py
    python scripts/gen_median_networks.py --check  # verify the networks, write nothing
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from lfsf._errors import ArgumentParser  # (usage errors in one line)

SIZES = (9, 25, 49)
#: The pair networks' wires (:func:`pair_network`): a block for each of the 2r shared
#: columns (its 2r+1 sorted values "v", padded by −∞ "-" below or +∞ "+" above) and
#: blocks of padding up to a power of two blocks.
PAIR_LAYOUTS = {
    1: "vvv+vvv+",
    2: "vvvvv+++" * 4,
    3: "++++++++vvvvvvv+++++++++vvvvvvv+-vvvvvvv-vvvvvvv-vvvvvvv-vvvvvvv",
}
OUT = Path(__file__).resolve().parents[1] / "kernels" / "median_networks.py"


def odd_even_merge_sort(n: int, block: int = 1) -> list[tuple[int, int]]:
    """Batcher's odd–even merge sort on n = 2^k wires: comparators (i, j), i < j, which
    put the smaller value on wire i. With ``block`` > 1 (a power of two), the wires come
    sorted in blocks of that many and the comparators that sort each block are left out."""
    comparators: list[tuple[int, int]] = []

    def merge(lo: int, hi: int, r: int) -> None:
        step = 2 * r
        if step < hi - lo:
            merge(lo, hi, step)
            merge(lo + r, hi, step)
            comparators.extend((i, i + r) for i in range(lo + r, hi - r, step))
        else:
            comparators.append((lo, lo + r))

    def sort(lo: int, hi: int) -> None:
        if hi > lo:
            mid = lo + (hi - lo) // 2
            sort(lo, mid)
            sort(mid + 1, hi)
            if hi - lo + 1 > block:
                merge(lo, hi, 1)

    sort(0, n - 1)
    return comparators


def median_network(n: int) -> tuple[list[tuple], int]:
    """The operations selecting the median of n values (n odd) and the wire it ends on.
    Operations: ("swap", i, j) relabels two wires; ("ce", i, j, keep_min, keep_max)
    compares wires i < j and keeps the outputs flagged."""
    size = 1 << (n - 1).bit_length()
    low = (size - n) // 2
    kind = ["v"] * n + ["-"] * low + ["+"] * (size - n - low)  # value, −∞, +∞
    target = n // 2 + low
    return pruned(kind, odd_even_merge_sort(size), {target}), target


def pruned(kind: list[str], comparators: list[tuple[int, int]], targets: set[int]) -> list[tuple]:
    """The operations of ``comparators`` on wires of ``kind`` ("v" a value, "-" −∞, "+"
    +∞) that the wires ``targets`` depend on, as :func:`median_network` describes."""
    kind = list(kind)
    ops: list[tuple] = []
    for i, j in comparators:
        a, b = kind[i], kind[j]
        if a == "-" or b == "+":
            continue  # ordered whatever the value
        if a == "+" or b == "-":
            kind[i], kind[j] = b, a
            ops.append(("swap", i, j))
            continue
        ops.append(("ce", i, j))
    need = set(targets)
    kept: list[tuple] = []
    for op in reversed(ops):
        _, i, j = op
        ni, nj = i in need, j in need
        if op[0] == "swap":
            need -= {i, j}
            need |= {j} if ni else set()
            need |= {i} if nj else set()
            kept.append(op)
        elif ni or nj:
            kept.append(("ce", i, j, ni, nj))
            need |= {i, j}
    kept.reverse()
    return kept


def run_network(ops: list[tuple], target: int, values: np.ndarray) -> np.ndarray:
    """Apply the network to rows of ``values`` (NumPy): what the generated code computes."""
    n = values.shape[1]
    size = 1 << (n - 1).bit_length()
    low = (size - n) // 2
    wires = np.concatenate([values, np.full((len(values), low), -np.inf),
                            np.full((len(values), size - n - low), np.inf)], 1)
    return apply(ops, wires)[:, target]


def apply(ops: list[tuple], wires: np.ndarray) -> np.ndarray:
    """``wires`` (a case a row, a wire a column) after the operations, in place."""
    for op in ops:
        i, j = op[1], op[2]
        if op[0] == "swap":
            wires[:, [i, j]] = wires[:, [j, i]]
        else:
            lo, hi = np.minimum(wires[:, i], wires[:, j]), np.maximum(wires[:, i], wires[:, j])
            wires[:, i], wires[:, j] = lo, hi
    return wires


def column_network(side: int) -> list[tuple]:
    """The operations sorting ``side`` values (the rest of the next power of two wires +∞)."""
    size = 1 << (side - 1).bit_length()
    return pruned(["v"] * side + ["+"] * (size - side), odd_even_merge_sort(size), set(range(side)))


def pair_network(r: int) -> tuple[list[tuple], list[int], int]:
    """The operations that put the ranks n//2 − (2r+1) … n//2 of the 2r sorted shared
    columns' values on the wires returned (ascending), laid out as PAIR_LAYOUTS[r] says,
    and the layout's block size."""
    layout, side = PAIR_LAYOUTS[r], 2 * r + 1
    blocks = 1 << (2 * r - 1).bit_length()
    block = len(layout) // blocks
    median = side * side // 2
    low = layout.count("-")
    targets = list(range(low + median - side, low + median + 1))
    return pruned(list(layout), odd_even_merge_sort(len(layout), block), set(targets)), targets, block


def column_wires(r: int) -> list[int]:
    """The first wire of each shared column in PAIR_LAYOUTS[r], the columns in order."""
    layout = PAIR_LAYOUTS[r]
    block = len(layout) // (1 << (2 * r - 1).bit_length())
    parts = [layout[k:k + block] for k in range(0, len(layout), block)]
    return [k * block + part.index("v") for k, part in enumerate(parts) if "v" in part]


def run_pair(r: int, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The medians of the windows of columns 0 … 2r and 1 … 2r+1 of ``columns`` (cases,
    2r+1 rows, 2r+2 columns, each column sorted), as the generated code takes them."""
    layout, side = PAIR_LAYOUTS[r], 2 * r + 1
    ops, targets, block = pair_network(r)
    wires = np.where(np.array([c == "-" for c in layout]), -np.inf, np.inf)[None].repeat(len(columns), 0)
    for c, first in enumerate(column_wires(r)):
        wires[:, first:first + side] = columns[:, :, 1 + c]
    shared = apply(ops, wires)[:, targets]
    medians = []
    for own in (columns[:, :, 0], columns[:, :, 2 * r + 1]):
        m = shared[:, -1]
        for k in range(1, side + 1):
            m = np.minimum(m, np.maximum(shared[:, -1 - k], own[:, k - 1]))
        medians.append(m)
    return medians[0], medians[1]


def check_pair_exhaustively(r: int) -> None:
    """The pair network and the selections, on every window of sorted 0/1 columns (a column
    is fixed by its count of ones: (2r+2)^(2r+1) windows, 2 097 152 at radius 3, each
    window's own column in turn): by the 0–1 principle, which holds for any network of
    min and max, they then select the median of any values."""
    side = 2 * r + 1
    total = (side + 1) ** side
    ranks = np.arange(side)
    for start in range(0, total, 1 << 17):
        index = np.arange(start, min(total, start + (1 << 17)))
        counts = np.stack([(index // (side + 1) ** c) % (side + 1) for c in range(side)], 1)
        columns = (ranks[None, :, None] >= side - counts[:, None, :]).astype(np.float32)  # ascending
        columns = np.concatenate([columns, columns[:, :, :1]], 2)  # (the right window's own column: the left's)
        want = (counts.sum(1) > side * side // 2).astype(np.float32)
        left, right = run_pair(r, columns)
        assert np.array_equal(left, want) and np.array_equal(right, want), f"pair network {r} is wrong"


def check_pair(r: int) -> None:
    """The column sort and the pair network select both windows' medians, on random, tied
    and 0/1 windows (:func:`check_pair_exhaustively` covers every 0/1 window)."""
    side = 2 * r + 1
    rng = np.random.default_rng(r)
    tests = [rng.standard_normal((2000, side, side + 1)), rng.integers(0, 3, (2000, side, side + 1)).astype(float),
             np.zeros((1, side, side + 1))]
    for ones in range(side * (side + 1) + 1):  # the 0–1 principle on random 0/1 inputs of every count of ones
        values = np.zeros((100, side * (side + 1)))
        for row in values:
            row[rng.choice(values.shape[1], ones, replace=False)] = 1.0
        tests.append(values.reshape(100, side, side + 1))
    sort = column_network(side)
    size = 1 << (side - 1).bit_length()
    for values in tests:
        columns = np.empty_like(values)
        for c in range(side + 1):
            wires = np.concatenate([values[:, :, c], np.full((len(values), size - side), np.inf)], 1)
            columns[:, :, c] = apply(sort, wires)[:, :side]
        assert np.array_equal(columns, np.sort(values, axis=1)), f"column sort of {side} is wrong"
        left, right = run_pair(r, columns)
        n = len(values)
        assert np.array_equal(left, np.median(values[:, :, :side].reshape(n, -1), axis=1)), f"pair network {r} is wrong"
        assert np.array_equal(right, np.median(values[:, :, 1:].reshape(n, -1), axis=1)), f"pair network {r} is wrong"


def check(n: int) -> None:
    ops, target = median_network(n)
    rng = np.random.default_rng(n)
    tests = [rng.standard_normal((2000, n)), rng.integers(0, 3, (2000, n)).astype(float), np.zeros((1, n))]
    if n <= 9:  # every 0/1 input (the 0–1 principle: then it selects for every input)
        tests.append(np.array(list(itertools.product((0.0, 1.0), repeat=n))))
    for values in tests:
        got = run_network(ops, target, values)
        assert np.array_equal(got, np.median(values, axis=1)), f"median network of {n} is wrong"
    if n > 9:  # the 0–1 principle on random 0/1 inputs of every count of ones
        for ones in range(n + 1):
            values = np.zeros((200, n))
            for row in values:
                row[rng.choice(n, ones, replace=False)] = 1.0
            assert np.array_equal(run_network(ops, target, values), np.median(values, axis=1))


def emit(n: int) -> tuple[str, int]:
    ops, target = median_network(n)
    name = {v: f"a{v}" for v in range(n)}  # wire -> variable
    lines = [
        "@wp.func",
        f"def median{n}(vals: vec49):",
        f'    """The median of vals[0 … {n - 1}] (selection network, generated)."""',
    ]
    lines += [f"    a{v} = vals[{v}]" for v in range(n)]
    body, count = comparator_lines(ops, name)
    lines += body
    lines.append(f"    return {name[target]}")
    return "\n".join(lines) + "\n", count


def comparator_lines(ops: list[tuple], name: dict) -> tuple[list[str], int]:
    """The min/max code of the operations on the variables ``name`` (wire → variable,
    relabelled in place) and its count of operations."""
    lines: list[str] = []
    count = 0
    for op in ops:
        i, j = op[1], op[2]
        if op[0] == "swap":
            name[i], name[j] = name.get(j), name.get(i)
            continue
        _, _, _, keep_min, keep_max = op
        x, y = name[i], name[j]
        if keep_min and keep_max:
            lines += [f"    t = at_most({x}, {y})", f"    {y} = at_least({x}, {y})", f"    {x} = t"]
            count += 2
        elif keep_min:
            lines.append(f"    {x} = at_most({x}, {y})")
            count += 1
        else:
            lines.append(f"    {y} = at_least({x}, {y})")
            count += 1
    return lines, count


def emit_column(r: int) -> str:
    """``sorted_flow_column{r}``: the window column's u and v sorted (column_network), and
    the least and greatest δ1 in it."""
    side = 2 * r + 1
    lines = [
        "@wp.func",
        f"def sorted_flow_column{r}(x: wp.array2d(dtype=Any), i: int, j: int, cu: wp.array3d(dtype=float),",
        "                         cv: wp.array3d(dtype=float), depth: wp.array2d(dtype=wp.vec2)):",
        f'    """u and v (components 2, 3 of x as (δ1, δ2, u, v)) of rows i − {r} … i + {r} of column j, clamped',
        f'    at the borders, sorted into cu[i, j, 0 … {side - 1}] and cv[i, j, 0 … {side - 1}] (sorting network,',
        '    generated), and the least and greatest δ1 among them into depth[i, j]."""',
        "    h = x.shape[0]",
    ]
    for t in range(side):
        lines += [f"    p = to_vec4(x[wp.clamp(i + {t - r}, 0, h - 1), j])", f"    u{t} = p[2]", f"    v{t} = p[3]"]
        lines += ["    lo = p[0]", "    hi = p[0]"] if t == 0 else [
            "    lo = at_most(lo, p[0])", "    hi = at_least(hi, p[0])"]
    lines.append("    depth[i, j] = wp.vec2(lo, hi)")
    ops = column_network(side)
    for c in "uv":
        body, _ = comparator_lines(ops, name := {t: f"{c}{t}" for t in range(side)})
        lines += body
        lines += [f"    c{c}[i, j, {t}] = {name[t]}" for t in range(side)]
    return "\n".join(lines) + "\n"


def emit_pair(r: int) -> tuple[str, int]:
    """``pair_medians{r}``: the medians of the windows at (i, j) and (i, j + 1) from their
    sorted columns (pair_network and the selection of :func:`run_pair`)."""
    side = 2 * r + 1
    ops, targets, _ = pair_network(r)
    name = {}
    for c, first in enumerate(column_wires(r)):
        name.update({first + t: f"c{c}_{t}" for t in range(side)})
    lines = [
        "@wp.func",
        f"def pair_medians{r}(c: wp.array3d(dtype=float), i: int, j: int, w: int):",
        f'    """The medians of the {side}×{side} windows at (i, j) and (i, j + 1) (columns clamped at',
        f"    the borders) from their columns sorted into c[i, column, 0 … {side - 1}] (the shared columns'",
        '    ranks by a pruned merging network, then each window\'s own column; generated)."""',
    ]
    for c in range(2 * r):
        lines.append(f"    j{c} = wp.clamp(j + {c - r + 1}, 0, w - 1)")
    for c in range(2 * r):
        lines += [f"    c{c}_{t} = c[i, j{c}, {t}]" for t in range(side)]
    body, count = comparator_lines(ops, name)
    lines += body
    shared = [name[t] for t in targets]
    for own, offset in (("left", -r), ("right", r + 1)):
        lines += [f"    k = wp.clamp(j + {offset}, 0, w - 1)", f"    {own} = {shared[-1]}"]
        lines += [f"    {own} = at_most({own}, at_least({shared[-1 - k]}, c[i, k, {k - 1}]))" for k in range(1, side + 1)]
    lines.append("    return left, right")
    return "\n".join(lines) + "\n", count


def main() -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="verify the networks only")
    args = parser.parse_args()
    for n in SIZES:
        check(n)
    for r in PAIR_LAYOUTS:
        check_pair(r)
        check_pair_exhaustively(r)
    if args.check:
        print("networks verified:", ", ".join(str(n) for n in SIZES), "and the pairs of radius",
              ", ".join(str(r) for r in PAIR_LAYOUTS))
        return
    parts = []
    for n in SIZES:
        code, count = emit(n)
        parts.append(code)
        print(f"median of {n}: {count} min/max operations")
    for r in PAIR_LAYOUTS:
        parts.append(emit_column(r))
        code, count = emit_pair(r)
        parts.append(code)
        print(f"radius {r} pair: {count} min/max operations on the shared columns")
    header = (
        '"""Selection networks for the median of 9, 25 and 49 values, and the sorted-column\n'
        "networks of the plain median of two neighbouring windows: branch-free straight-line\n"
        "min/max code. GENERATED by scripts/gen_median_networks.py (which documents and checks\n"
        'the construction); do not edit."""\n\n'
        "from typing import Any\n\n"
        "import warp as wp\n\n"
        "from .common import at_least, at_most, to_vec4\n\n"
        'wp.set_module_options({"enable_backward": False})\n\n'
        "vec49 = wp.types.vector(length=49, dtype=wp.float32)\n\n\n"
    )
    OUT.write_text(header + "\n\n".join(parts))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
