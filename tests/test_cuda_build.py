"""scripts/cuda_build.py: every kernel builds for CUDA on this machine (Warp's NVRTC, no
GPU needed), and the resources read from the cubins are the ones the kernels ask for."""

import pytest
from conftest import load_script

ARCH = 90  # H100 and H200, the GPUs lent to this project


def test_every_kernel_builds_for_cuda_with_its_register_caps(tmp_path, capsys):
    """Each kernel of lfsf.kernels, in each of its overloads, is an entry point of its
    module's cubin for sm_90, with 1–255 registers; the kernels built with
    ``cuda_max_registers`` stay within their caps. A kernel that only fails on CUDA
    (a construct its code generator or NVRTC refuses) fails this test on a machine
    without a GPU."""
    import warp as wp

    from lfsf.kernels import data_term, tgv

    script = load_script("cuda_build")
    if ARCH not in wp.get_cuda_supported_archs():
        pytest.skip(f"this Warp has no NVRTC for sm_{ARCH}")
    rows = script.build(ARCH, tmp_path)
    built = {row["hash"] for row in rows}
    wanted = {}
    for name, module in script.kernel_modules():
        for attr, kernel in vars(module).items():
            if isinstance(kernel, wp.Kernel):
                hashes = [o.hash for o in kernel.overloads.values()] if kernel.is_generic else [kernel.hash]
                for h in hashes:
                    wanted[h[:4].hex()] = f"{name}.{attr}"
    missing = sorted(v for k, v in wanted.items() if k not in built)
    assert not missing, f"kernels without a CUDA entry point: {missing}"
    assert len(wanted) > 60
    assert all(1 <= row["registers"] <= 255 and row["local_bytes"] >= 0 for row in rows)
    by_name = {}
    for row in rows:
        by_name.setdefault((row["module"], row["kernel"]), []).append(row)
    caps = {("data_term", "data_coefficients"): data_term.COEFFICIENT_REGISTERS,
            ("tgv", "tgv_primal_step_pixel"): tgv.PRIMAL_REGISTERS}
    for key, cap in caps.items():
        assert len(by_name[key]) == 2, key  # the vec4 and the vec2 overloads
        assert all(row["registers"] <= cap for row in by_name[key]), (key, by_name[key])
    # the per-pixel dual step of the data term, the hottest kernel on a GPU, needs no cap
    assert all(row["registers"] < 255 for row in by_name[("data_term", "dual_data_step_pixel")])


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
