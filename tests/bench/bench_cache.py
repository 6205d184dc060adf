"""Speed goals of the content-checked caches and the checked JPEG decode.

- Checking that 1000 recorded input files are unchanged (what every up-to-date stage does before
  it is skipped): goal under 0.1 s (size and mtime match, nothing is read).
- Hashing 1000 AVD-size JPEG files when their mtimes changed (a copied dataset): goal under 2 s.
- Decoding a JPEG with libjpeg's warnings captured (``loaders.jpeg.decode_jpeg``) against the
  same decode without the capture (marker check, ``cv2.imdecode``, BGR -> RGB): goal under 1.15x
  (the capture redirects one file descriptor per image).

Prints measured values and their ratios to the goals (ratio < 1 = goal met).
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

N_FILES = 1000
FILE_BYTES = 150_000          # about a 1920x1080 AVD JPEG at quality 90 is 150-400 kB
GOAL_CHECK_S, GOAL_REHASH_S, GOAL_DECODE_RATIO = 0.1, 2.0, 1.15


def main() -> None:
    import cv2
    import numpy as np

    from loaders.image_gate import check_jpeg_complete
    from loaders.jpeg import decode_jpeg
    from pipeline.infra.cache import file_record, record_changed

    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        blob = rng.bytes(FILE_BYTES)
        for i in range(N_FILES):
            p = Path(tmp) / f"{i:04d}.jpg"
            p.write_bytes(blob[i:] + blob[:i])
            paths.append(p)
        recs = {p: file_record(p) for p in paths}
        t = time.perf_counter()
        assert all(record_changed(p, r) is None for p, r in recs.items())
        check = time.perf_counter() - t
        for p in paths:
            st = p.stat()
            os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 1000))
        t = time.perf_counter()
        assert all(record_changed(p, r) is None for p, r in recs.items())
        rehash = time.perf_counter() - t
    print(f"bench_cache: {N_FILES} unchanged inputs checked in {check:.3f} s (goal {GOAL_CHECK_S} s, "
          f"ratio {check / GOAL_CHECK_S:.2f}); re-hashed after touch in {rehash:.2f} s "
          f"({N_FILES} x {FILE_BYTES // 1000} kB; goal {GOAL_REHASH_S} s, ratio {rehash / GOAL_REHASH_S:.2f})")

    img = (rng.random((1080, 1920, 3)) * 255).astype(np.uint8)
    img = cv2.GaussianBlur(img, (0, 0), 3)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    data = buf.tobytes()
    n = 30

    def timed(fn) -> float:
        fn()
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        return (time.perf_counter() - t0) / n

    def uncaptured():
        check_jpeg_complete(data, Path("bench.jpg"))
        bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        return np.ascontiguousarray(bgr[:, :, ::-1])

    plain, checked = [], []
    for _ in range(3):  # interleaved, best of three: the machine is shared
        plain.append(timed(uncaptured))
        checked.append(timed(lambda: decode_jpeg(data, "bench.jpg")))
    plain, checked = min(plain), min(checked)
    ratio = checked / plain
    print(f"bench_cache: 1920x1080 JPEG ({len(data) // 1000} kB) decode {plain * 1000:.1f} ms without "
          f"the capture, {checked * 1000:.1f} ms with it: {ratio:.2f}x (goal {GOAL_DECODE_RATIO}x, "
          f"ratio {ratio / GOAL_DECODE_RATIO:.2f})")


if __name__ == "__main__":
    main()
