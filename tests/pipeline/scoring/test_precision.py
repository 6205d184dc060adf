"""``precision = "auto"`` trains in bf16 only on hardware with native bf16: oneDNN also runs bf16
autocast on plain AVX-512 CPUs by emulation, where a step costs about 2.4x fp32's CPU time."""
import pytest
import torch

from pipeline.scoring.training import NATIVE_BF16_FLAGS, resolve_precision

AVX512 = {"avx2", "fma", "avx512f", "avx512bw", "avx512_vnni"}


def test_auto_is_fp32_on_a_cpu_without_native_bf16():
    assert resolve_precision("auto", "cpu", flags=AVX512) == "fp32"
    assert resolve_precision("auto", "cpu", flags=set()) == "fp32"   # flags unknown: the safe choice


@pytest.mark.parametrize("flag", NATIVE_BF16_FLAGS)
def test_auto_is_bf16_with_a_native_bf16_flag_where_onednn_has_it(flag):
    expected = "bf16" if torch.ops.mkldnn._is_mkldnn_bf16_supported() else "fp32"
    assert resolve_precision("auto", "cpu", flags=AVX512 | {flag}) == expected


def test_an_explicit_precision_is_kept_and_a_wrong_one_named():
    assert resolve_precision("bf16", "cpu", flags=set()) == "bf16"
    assert resolve_precision("fp32", "cpu", flags=AVX512 | {"amx_bf16"}) == "fp32"
    with pytest.raises(ValueError, match="fp16"):
        resolve_precision("fp16", "cpu")
