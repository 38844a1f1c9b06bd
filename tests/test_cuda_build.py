"""The CUDA build of every kernel, on any machine (scripts/cuda_build.py: Warp's bundled
NVRTC builds cubins without a GPU), and the resources read from the cubins."""

import pytest
from conftest import load_script

ARCH = 90  # H100 and H200, the GPUs lent to this project


def _module_names():
    return [name for name, _module in load_script("cuda_build").kernel_modules()]


@pytest.mark.parametrize("name", _module_names())
def test_kernel_module_compiles_for_cuda(name, tmp_path):
    """The module builds to an sm_90 cubin, and each of its kernels, in each overload,
    is an entry point there with 1–255 registers; the kernels built with
    ``cuda_max_registers`` stay within their caps. A kernel that fails only on CUDA (a
    construct Warp's CUDA code generator or NVRTC refuses, such as the CPU-only
    instances' native code) fails here on a machine without a GPU; running the kernels
    is what the tests on ``cuda:0`` do where one is present."""
    import warp as wp

    from lfsf.kernels import data_term, tgv

    script = load_script("cuda_build")
    if ARCH not in script.nvrtc_archs():
        pytest.skip(f"this Warp has no NVRTC for sm_{ARCH}")
    rows = script.build(ARCH, tmp_path, modules=[name])
    module = dict(script.kernel_modules())[name]
    wanted = {}
    for attr, kernel in vars(module).items():
        if isinstance(kernel, wp.Kernel):
            for overload in kernel.overloads.values() if kernel.is_generic else [kernel]:
                wanted[overload.hash[:4].hex()] = attr
    built = {row["hash"] for row in rows}
    assert wanted and not sorted(v for k, v in wanted.items() if k not in built), "kernels without a CUDA entry point"
    assert all(1 <= row["registers"] <= 255 and row["local_bytes"] >= 0 for row in rows)
    caps = {("data_term", "data_coefficients"): data_term.COEFFICIENT_REGISTERS,
            ("tgv", "tgv_primal_step_pixel"): tgv.PRIMAL_REGISTERS}
    for (mod, kernel), cap in caps.items():
        if mod == name:
            capped = [row for row in rows if row["kernel"] == kernel]
            assert len(capped) == 2  # the vec4 and the vec2 overloads
            assert all(row["registers"] <= cap for row in capped), capped


def test_cuda_build_refuses_bad_input(tmp_path, capsys):
    """A file that is not a cubin, an architecture NVRTC does not know, and bad
    arguments: clear errors, exit status 2."""
    script = load_script("cuda_build")
    not_cubin = tmp_path / "x.cubin"
    not_cubin.write_bytes(b"not an ELF file at all")
    with pytest.raises(ValueError, match="not a 64-bit"):
        script.cubin_resources(not_cubin)
    assert script.main(["--arch", "12"]) == 2
    assert "cannot build CUDA code for sm_12" in capsys.readouterr().err
    assert script.main(["--arch", "ninety"]) == 2
    assert script.main(["--modules", "pyramid", "nothing"]) == 2
    assert "no kernel module nothing" in capsys.readouterr().err


def test_cuda_build_writes_its_table_and_json(tmp_path, capsys):
    """One module's build through the command: the table on stdout, the rows as JSON
    (written whole), the .cu source and cubin kept in --out."""
    import json

    script = load_script("cuda_build")
    if ARCH not in script.nvrtc_archs():
        pytest.skip(f"this Warp has no NVRTC for sm_{ARCH}")
    out = tmp_path / "rows.json"
    assert script.main(["--modules", "pyramid", "--json", str(out), "--out", str(tmp_path / "build")]) == 0
    report = json.loads(out.read_text())
    assert report["arch"] == ARCH
    assert {row["kernel"] for row in report["kernels"]} == {"downsample", "downsample_rows", "upsample", "upsample_unknowns"}
    assert "| pyramid | downsample |" in capsys.readouterr().out
    assert list((tmp_path / "build").glob("*.cubin")) and list((tmp_path / "build").glob("*.cu"))
    assert not list(tmp_path.glob("*.tmp"))
