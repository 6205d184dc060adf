"""What can make trained weights differ across machines: the CPU features that select different
oneDNN/BLAS kernels (and so different rounding) for the same training code."""
from __future__ import annotations

import re

import numpy as np
import torch


# CPU features that select different oneDNN/BLAS kernels (and so different rounding) for the same
# training code: bf16/AMX paths exist only on some CPUs; AVX-512 vs AVX2 changes the reduction order.
KERNEL_FLAGS = ("avx2", "fma", "avx512f", "avx512bw", "avx512_vnni", "avx512_bf16", "avx512_fp16",
                "amx_tile", "amx_bf16", "amx_int8")
CROSS_MACHINE_NOTE = (
    "Same machine, same seed, same thread count: byte-identical weights. On another machine the "
    "weights (and so every score downstream) can differ in the last bits and then drift during "
    "training, because oneDNN picks kernels by CPU features (the cpu_flags here: bf16/AMX "
    "autocast exists only where avx512_bf16/amx_bf16 do, AVX-512 vs AVX2 changes summation "
    "order) and by thread count, and library versions change kernels too; the seed study "
    "(viewfuse study) measures how much a verdict depends on one training run.")


def cpu_model() -> str:
    """The processor's model name (/proc/cpuinfo), else what ``platform.processor()`` says (on Linux
    that is often only the architecture, so /proc/cpuinfo comes first)."""
    import platform

    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:  # not Linux
        pass
    return platform.processor() or platform.machine() or "unknown"


def cpu_flags() -> set[str]:
    """The processor's feature flags (/proc/cpuinfo; empty where unknown)."""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:  # not Linux: flags unknown
        pass
    return set()


def blas_info() -> dict:
    """Which BLAS/LAPACK torch and numpy were built with (their own build reports, briefly)."""
    out: dict = {}
    try:  # torch: "BLAS_INFO=mkl, ..., LAPACK_INFO=mkl" and the MKL / oneDNN version lines
        text = torch.__config__.show()
        for key in ("BLAS_INFO", "LAPACK_INFO"):
            m = re.search(rf"{key}=([^,\s]+)", text)
            out[f"torch_{key.lower()}"] = m.group(1) if m else None
        for line in text.splitlines():
            line = line.strip(" -")
            if line.startswith(("Intel(R) oneAPI Math Kernel Library Version", "Intel(R) MKL-DNN", "OpenBLAS")):
                out.setdefault("torch_libraries", []).append(line.split(" (Git Hash")[0].split("-Product")[0])
    except Exception as e:  # noqa: BLE001 -- a build report is best effort; say why it is missing
        out["torch_error"] = f"{type(e).__name__}: {e}"
    try:  # numpy >= 1.25: the build's dependency dict
        deps = np.show_config(mode="dicts").get("Build Dependencies", {})
        for key in ("blas", "lapack"):
            d = deps.get(key) or {}
            out[f"numpy_{key}"] = f"{d.get('name', '?')} {d.get('version', '?')}".strip()
    except Exception as e:  # noqa: BLE001
        out["numpy_error"] = f"{type(e).__name__}: {e}"
    return out


def machine_fingerprint() -> dict:
    """CPU model, torch's CPU capability and kernel-relevant flags, thread count, BLAS and library
    versions (for card.json and the report's run details)."""
    import platform

    flags = cpu_flags()
    versions = {"torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version()}
    for mod in ("torchvision", "cv2"):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:  # pragma: no cover
            versions[mod] = None
    try:
        capability = torch.backends.cpu.get_cpu_capability()
    except AttributeError:  # torch < 2.1
        capability = None
    return {"cpu_model": cpu_model(), "cpu_capability": capability,
            "cpu_flags": [f for f in KERNEL_FLAGS if f in flags],
            "machine": platform.machine(), "torch_threads": torch.get_num_threads(),
            "onednn": bool(torch.backends.mkldnn.is_available()), "blas": blas_info(), "versions": versions,
            "cross_machine": CROSS_MACHINE_NOTE}

