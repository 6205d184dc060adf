"""The classifier card's machine block names what moves trained weights between machines: the
processor's model (from /proc/cpuinfo, not the bare architecture platform.processor() gives on
Linux), torch's CPU capability, the thread count and the BLAS torch and numpy were built with."""
from __future__ import annotations

from pathlib import Path

import torch

from pipeline.infra.fingerprint import machine_fingerprint
from reports.main.track import machine_text


def test_the_fingerprint_names_processor_capability_threads_and_blas():
    fp = machine_fingerprint()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        names = [ln.split(":", 1)[1].strip() for ln in cpuinfo.read_text().splitlines() if ln.startswith("model name")]
        if names:
            assert fp["cpu_model"] == names[0]
    assert fp["cpu_model"]
    assert fp["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert fp["torch_threads"] == torch.get_num_threads()
    blas = fp["blas"]
    assert blas.get("torch_blas_info") or blas.get("torch_error")
    assert blas.get("numpy_blas") or blas.get("numpy_error")


def test_the_run_details_line_says_which_machine_or_that_it_is_unknown():
    fp = machine_fingerprint()
    line = machine_text(fp)
    assert line.startswith(fp["cpu_model"]) and f"{fp['torch_threads']} threads" in line
    assert str(fp["cpu_capability"]) in line
    assert "not recorded" in machine_text(None) and "not recorded" in machine_text({})
