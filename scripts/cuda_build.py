"""Every kernel of lfsf.kernels built for CUDA on a machine without a GPU, with what each
kernel's thread takes there: registers and local memory.

Warp carries NVIDIA's run-time compiler (NVRTC) in its own library, so it builds the CUDA
code of a module for a GPU architecture without a GPU or a driver
(``wp.compile_aot_module``, here to a cubin per module). This script builds every kernel
module of ``lfsf.kernels`` that way, so that a kernel which does not compile for CUDA is
found on this machine (and in CI) before a GPU user meets it, and reads from each cubin
the resources its kernels were given (the per-kernel attributes of its ``.nv.info``
section):

* ``registers`` a thread (at most 255; a kernel's ``cuda_max_registers`` caps it), which
  bound how many threads a streaming multiprocessor keeps in flight;
* ``local_bytes``, the thread's stack frame in local memory (device memory behind the L1):
  registers spilled under a cap, and arrays indexed at run time. Not zero marks a kernel
  whose speed on a GPU depends on it.

Usage: ``python scripts/cuda_build.py [--arch 90] [--out DIR] [--json FILE] [--modules
NAME …]``. It prints a
table of kernel, overload, registers and local bytes per module. Exit status 0; 1 when a
module does not build (its error is printed); 2 for bad arguments or a Warp without NVRTC.
``--arch`` is a compute capability without its dot (90: H100 and H200, 80: A100, 89: L4 and
RTX 40xx); ``--out`` keeps the generated ``.cu`` sources and cubins (a temporary folder
otherwise).
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import re
import struct
import sys
import tempfile
import time
from pathlib import Path

#: The .nv.info attributes read (NVIDIA's EIATTR codes, as cuobjdump names them):
#: REGCOUNT and FRAME_SIZE, each a (symbol index, value) pair of 32-bit words.
EIATTR_FRAME_SIZE = 0x11
EIATTR_REGCOUNT = 0x2F
#: .nv.info's formats: no value (EIFMT_NVAL, 2 bytes in all), a value of the length that
#: follows (EIFMT_SVAL); the others (a byte, a half word) take 4 bytes in all.
EIFMT_NVAL, EIFMT_SVAL = 1, 4

#: A kernel's CUDA entry point as Warp names it: key, hash of the overload, suffix.
ENTRY = re.compile(r"^(?P<key>.+)_(?P<hash>[0-9a-f]{8})_cuda_kernel_forward$")


class BuildError(RuntimeError):
    """A kernel module that did not build for CUDA."""


def _sections(data: bytes) -> dict[str, tuple[int, int]]:
    """Section name → (offset, size) of a 64-bit little-endian ELF file (a cubin)."""
    if data[:4] != b"\x7fELF" or data[4] != 2 or data[5] != 1:
        raise ValueError("not a 64-bit little-endian ELF file")
    shoff = struct.unpack_from("<Q", data, 0x28)[0]
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x3A)
    headers = [struct.unpack_from("<IIQQQQIIQQ", data, shoff + k * shentsize) for k in range(shnum)]
    names_at = headers[shstrndx][4]

    def name(offset):
        start = names_at + offset
        return data[start:data.index(b"\0", start)].decode()

    return {name(h[0]): (h[4], h[5]) for h in headers}


def cubin_resources(path) -> dict[str, dict[str, int]]:
    """Entry point → {"registers", "local_bytes"} of every kernel in the cubin at
    ``path``, read from the attributes of its ``.nv.info`` section (registers from
    REGCOUNT, the stack frame in local memory from FRAME_SIZE; a kernel without a frame
    attribute has none)."""
    data = Path(path).read_bytes()
    sections = _sections(data)
    if ".nv.info" not in sections or ".symtab" not in sections or ".strtab" not in sections:
        raise ValueError(f"{path}: no .nv.info, .symtab or .strtab section: not a cubin")
    symtab_at, _ = sections[".symtab"]
    strtab_at, _ = sections[".strtab"]

    def symbol(index):
        name_at = struct.unpack_from("<I", data, symtab_at + 24 * index)[0] + strtab_at
        return data[name_at:data.index(b"\0", name_at)].decode()

    registers, frames = {}, {}
    at, size = sections[".nv.info"]
    end = at + size
    while at < end:
        fmt, attribute = data[at], data[at + 1]
        if fmt == EIFMT_SVAL:
            length = struct.unpack_from("<H", data, at + 2)[0]
            if length == 8 and attribute in (EIATTR_REGCOUNT, EIATTR_FRAME_SIZE):
                index, value = struct.unpack_from("<II", data, at + 4)
                (registers if attribute == EIATTR_REGCOUNT else frames)[symbol(index)] = value
            at += 4 + length
        else:
            at += 2 if fmt == EIFMT_NVAL else 4
    return {name: {"registers": count, "local_bytes": frames.get(name, 0)}
            for name, count in registers.items() if ENTRY.match(name)}


def kernel_modules():
    """(name, module) of every module of lfsf.kernels that defines kernels, by name."""
    import warp as wp

    import lfsf.kernels as package

    found = []
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{package.__name__}.{info.name}")
        if wp.get_module(module.__name__).kernels:
            found.append((info.name, module))
    return found


def _names(module) -> dict[str, tuple[str, str]]:
    """Overload hash (the 8 hex digits of a CUDA entry point) → (the kernel's name in
    ``module``, its overload: "vec4" for the unknowns (δ1, δ2, u, v), "vec2" for the flow
    only, "" for a kernel that is not generic), for the kernels the module names (a public
    name before a private one). Read after a build, which gives the kernels their hashes."""
    import warp as wp

    found = {}
    for attr, kernel in sorted(vars(module).items(), key=lambda item: (item[0].startswith("_"), item[0])):
        if not isinstance(kernel, wp.Kernel):
            continue
        if kernel.is_generic:
            for signature, overload in kernel.overloads.items():
                # (by the arrays' type, a2v4f4: a kernel may take a plain vec4 beside arrays of vec2,
                # as pyramid.upsample_unknowns its scales)
                kind = "vec4" if "a2v4f4" in signature else "vec2" if "a2v2f4" in signature else signature
                if getattr(overload, "hash", None):
                    found.setdefault(overload.hash[:4].hex(), (attr, kind))
        elif getattr(kernel, "hash", None):
            found.setdefault(kernel.hash[:4].hex(), (attr, ""))
    return found


def nvrtc_archs() -> list[int]:
    """The compute capabilities this Warp's NVRTC builds for (none where Warp came
    without it, or is older than the functions this script needs)."""
    from lfsf import device

    wp = device.warp()  # (initialised quietly: no banner, no driver warning)
    if not (hasattr(wp, "compile_aot_module") and hasattr(wp, "get_cuda_supported_archs")):
        return []
    return list(wp.get_cuda_supported_archs())


def build(arch: int = 90, out: Path | None = None, progress=None, modules=None) -> list[dict]:
    """Build every kernel module (or those named in ``modules``, e.g. ["tgv"]) for
    compute capability ``arch`` into ``out`` (a temporary folder if None) and return a
    row per kernel overload: module, kernel (its name in its module, or Warp's key where
    the module has no name for it), overload ("vec4", "vec2" or ""), entry (the CUDA
    entry point), hash (the overload's 8 hex digits in it), registers, local_bytes, and
    the module's build seconds. Raises BuildError naming the module that does not build;
    ValueError for an ``arch`` that this Warp cannot build for (:func:`nvrtc_archs`) or
    a cubin whose attributes it does not read."""
    import warp as wp

    archs = nvrtc_archs()
    if arch not in archs:
        which = f"its NVRTC builds for {', '.join(map(str, archs))}" if archs else "no NVRTC or no compile_aot_module"
        raise ValueError(f"this Warp ({wp.config.version}) cannot build CUDA code for sm_{arch}: {which}")
    say = progress or (lambda _m: None)
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(out) if out is not None else Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        rows = []
        for name, module in kernel_modules():
            if modules is not None and name not in modules:
                continue
            t0 = time.perf_counter()
            try:
                paths = wp.compile_aot_module(module, arch=arch, module_dir=str(folder), use_ptx=False)
            except Exception as err:  # (NVRTC's and Warp's code-generation errors alike)
                raise BuildError(f"lfsf.kernels.{name} does not build for sm_{arch}: {err}") from err
            seconds = time.perf_counter() - t0
            say(f"{name}: {seconds:.1f} s")
            names = _names(module)
            resources_of = cubin_resources(paths[-1])
            if not resources_of:
                raise ValueError(f"{paths[-1]}: no kernel's registers found in the cubin (a format this script "
                                 "does not read)")
            for entry, resources in sorted(resources_of.items()):
                match = ENTRY.match(entry)
                kernel, overload = names.get(match["hash"], (match["key"], ""))
                rows.append({"module": name, "kernel": kernel, "overload": overload, "entry": entry,
                             "hash": match["hash"], **resources,
                             "build_seconds": round(seconds, 2)})
    return sorted(rows, key=lambda r: (r["module"], r["kernel"], r["overload"]))


def table(rows: list[dict], arch: int) -> str:
    """The rows as a Markdown table."""
    lines = [f"CUDA build for sm_{arch} (Warp's NVRTC, no GPU needed): registers and local memory a thread",
             "", "| module | kernel | overload | registers | local bytes |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['module']} | {r['kernel']} | {r['overload']} | {r['registers']} | {r['local_bytes']} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="cuda_build.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--arch", type=int, default=90, help="compute capability without the dot (default 90)")
    parser.add_argument("--out", type=Path, help="keep the .cu sources and cubins in this folder")
    parser.add_argument("--json", type=Path, help="write the rows as JSON to this file")
    parser.add_argument("--modules", nargs="+", metavar="NAME",
                        help="only these modules of lfsf.kernels (e.g. tgv data_term; default: all)")
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:
        return 2 if exit_.code else 0
    try:
        if args.modules:
            known = [name for name, _module in kernel_modules()]
            unknown = sorted(set(args.modules) - set(known))
            if unknown:
                raise ValueError(f"no kernel module {', '.join(unknown)} in lfsf.kernels (it has {', '.join(known)})")
        rows = build(args.arch, args.out, progress=lambda m: print(m, file=sys.stderr, flush=True),
                     modules=args.modules)
    except ValueError as err:
        print(f"cuda_build: {err}", file=sys.stderr)
        return 2
    except BuildError as err:
        print(f"cuda_build: {err}", file=sys.stderr)
        return 1
    print(table(rows, args.arch))
    if args.json is not None:
        tmp = args.json.with_name(args.json.name + ".tmp")
        tmp.write_text(json.dumps({"arch": args.arch, "kernels": rows}, indent=1))
        tmp.replace(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
