"""What can make trained weights differ across machines: the CPU features that select different
oneDNN/BLAS kernels (and so different rounding) for the same training code."""
from __future__ import annotations


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


def machine_fingerprint() -> dict:
    """CPU model and kernel-relevant flags, thread count and library versions (for card.json)."""
    import platform

    model, flags = platform.processor() or "", set()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name") and not model.strip():
                    model = line.split(":", 1)[1].strip()
                elif line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    break
    except OSError:  # not Linux: flags unknown
        pass
    versions = {"torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version()}
    for mod in ("torchvision", "cv2"):
        try:
            versions[mod] = __import__(mod).__version__
        except ImportError:  # pragma: no cover
            versions[mod] = None
    return {"cpu_model": model, "cpu_flags": [f for f in KERNEL_FLAGS if f in flags],
            "machine": platform.machine(), "torch_threads": torch.get_num_threads(),
            "onednn": bool(torch.backends.mkldnn.is_available()), "versions": versions,
            "cross_machine": CROSS_MACHINE_NOTE}
