"""Generate ``kernels/median_networks.py``: branch-free selection networks for the median
of 9, 25 and 49 values (the 3×3, 5×5 and 7×7 windows of the flow's median filter).

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

    python scripts/gen_median_networks.py          # rewrite kernels/median_networks.py
    python scripts/gen_median_networks.py --check  # verify the networks, write nothing
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from lfsf._errors import ArgumentParser  # (usage errors in one line)

SIZES = (9, 25, 49)
OUT = Path(__file__).resolve().parents[1] / "kernels" / "median_networks.py"


def odd_even_merge_sort(n: int) -> list[tuple[int, int]]:
    """Batcher's odd–even merge sort on n = 2^k wires: comparators (i, j), i < j, which
    put the smaller value on wire i."""
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
    ops: list[tuple] = []
    for i, j in odd_even_merge_sort(size):
        a, b = kind[i], kind[j]
        if a == "-" or b == "+":
            continue  # ordered whatever the value
        if a == "+" or b == "-":
            kind[i], kind[j] = b, a
            ops.append(("swap", i, j))
            continue
        ops.append(("ce", i, j))
    target = n // 2 + low
    need = {target}
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
    return kept, target


def run_network(ops: list[tuple], target: int, values: np.ndarray) -> np.ndarray:
    """Apply the network to rows of ``values`` (NumPy): what the generated code computes."""
    n = values.shape[1]
    size = 1 << (n - 1).bit_length()
    low = (size - n) // 2
    wires = np.concatenate([values, np.full((len(values), low), -np.inf),
                            np.full((len(values), size - n - low), np.inf)], 1)
    for op in ops:
        i, j = op[1], op[2]
        if op[0] == "swap":
            wires[:, [i, j]] = wires[:, [j, i]]
        else:
            lo, hi = np.minimum(wires[:, i], wires[:, j]), np.maximum(wires[:, i], wires[:, j])
            wires[:, i], wires[:, j] = lo, hi
    return wires[:, target]


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
    lines.append(f"    return {name[target]}")
    return "\n".join(lines) + "\n", count


def main() -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="verify the networks only")
    args = parser.parse_args()
    for n in SIZES:
        check(n)
    if args.check:
        print("networks verified:", ", ".join(str(n) for n in SIZES))
        return
    parts = []
    for n in SIZES:
        code, count = emit(n)
        parts.append(code)
        print(f"median of {n}: {count} min/max operations")
    header = (
        '"""Selection networks for the median of 9, 25 and 49 values: branch-free straight-line\n'
        "min/max code. GENERATED by scripts/gen_median_networks.py (which documents and checks\n"
        'the construction); do not edit."""\n\n'
        "import warp as wp\n\n"
        "from .common import at_least, at_most\n\n"
        'wp.set_module_options({"enable_backward": False})\n\n'
        "vec49 = wp.types.vector(length=49, dtype=wp.float32)\n\n\n"
    )
    OUT.write_text(header + "\n\n".join(parts))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
