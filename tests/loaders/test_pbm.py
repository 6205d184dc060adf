"""PBM (P4) masks: hand-made bytes decode with BigBIRD's polarity (bit 1 = black = object)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from loaders.errors import BadInputError
from loaders.pbm import encode_pbm, read_pbm, write_pbm

# A 10x3 mask, width not a multiple of 8: each row takes 2 bytes, the last 6 bits are padding.
#            pixel: 0123456789
EXPECTED_ROWS = ["1000000001",
                 "0110000010",
                 "0000000000"]
RASTER = bytes([0b10000000, 0b01000000,    # row 0: pixels 0 and 9 set
                0b01100000, 0b10000000,    # row 1: pixels 1, 2 and 8 set
                0b00000000, 0b00111111])   # row 2: nothing set; padding bits must be ignored


def _expected() -> np.ndarray:
    return np.array([[c == "1" for c in row] for row in EXPECTED_ROWS])


@pytest.mark.parametrize("header", [
    b"P4 10 3\n",                                  # BigBIRD's one-line header
    b"P4\n# made by hand\n10 3\n",                  # standard multi-line header with a comment
    b"P4\n10\n# width above, height below\n3\n",    # comment between the dimensions
])
def test_hand_made_pbm_decodes_with_bigbird_polarity(tmp_path, header):
    p = tmp_path / "m.pbm"
    p.write_bytes(header + RASTER)
    mask = read_pbm(p)
    assert mask.dtype == bool and mask.shape == (3, 10)
    np.testing.assert_array_equal(mask, _expected())


def test_opencv_agrees_bit_one_is_black(tmp_path):
    # An independent decoder: OpenCV gives 0 (black) exactly where we say "object".
    p = tmp_path / "m.pbm"
    p.write_bytes(b"P4\n# c\n10 3\n" + RASTER)
    grey = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    np.testing.assert_array_equal(grey == 0, read_pbm(p))


def test_encode_roundtrip_and_one_line_header(tmp_path):
    rng = np.random.default_rng(3)
    mask = rng.random((7, 13)) < 0.4
    data = encode_pbm(mask)
    assert data.startswith(b"P4 13 7\n")
    assert len(data) == len(b"P4 13 7\n") + 7 * 2
    write_pbm(tmp_path / "r.pbm", mask)
    np.testing.assert_array_equal(read_pbm(tmp_path / "r.pbm"), mask)


@pytest.mark.parametrize("data,problem", [
    (b"P1 10 3\n" + RASTER, "not a raw PBM"),
    (b"P4 10 3\n" + RASTER[:4], "truncated"),
    (b"P4 10\n", "header"),
    (b"P4 x 3\n" + RASTER, "corrupt PBM: bad size"),
])
def test_bad_pbm_names_file_and_problem(tmp_path, data, problem):
    p = tmp_path / "bad.pbm"
    p.write_bytes(data)
    with pytest.raises(BadInputError) as e:
        read_pbm(p)
    assert str(p) in str(e.value) and problem in str(e.value)


def test_missing_pbm(tmp_path):
    with pytest.raises(BadInputError, match="missing"):
        read_pbm(tmp_path / "none.pbm")
