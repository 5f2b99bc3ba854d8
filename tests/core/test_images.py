"""Image and disparity I/O at the edges of the core."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from shared.images import (
    ImageError,
    decode_image,
    load_disparity,
    load_image,
    load_pair,
    preview_png,
    save_disparity,
)


@pytest.fixture
def rgb() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)


def _expected_gray(bgr: np.ndarray, full_scale: float) -> np.ndarray:
    b, g, r = (bgr[..., i].astype(np.float64) / full_scale for i in range(3))
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


@pytest.mark.parametrize("suffix", [".png", ".ppm", ".bmp", ".tif"])
def test_colour_images_become_rec709_gray_in_unit_range(tmp_path, rgb, suffix):
    path = tmp_path / f"img{suffix}"
    cv2.imwrite(str(path), rgb)
    gray = load_image(path)
    assert gray.dtype == np.float32 and gray.shape == (5, 7)
    np.testing.assert_allclose(gray, _expected_gray(rgb, 255.0), atol=1e-5)


def test_sixteen_bit_png_uses_its_full_range(tmp_path):
    values = np.array([[0, 65535], [32768, 1000]], dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "g16.png"), values)
    np.testing.assert_allclose(load_image(tmp_path / "g16.png"), values / 65535.0, atol=1e-6)


def test_pgm_and_jpeg_load_as_gray(tmp_path):
    gray = np.linspace(0, 255, 48).reshape(6, 8).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "g.pgm"), gray)
    cv2.imwrite(str(tmp_path / "g.jpg"), gray)
    np.testing.assert_allclose(load_image(tmp_path / "g.pgm"), gray / 255.0, atol=1e-6)
    assert np.abs(load_image(tmp_path / "g.jpg") - gray / 255.0).max() < 0.05


def test_float_pfm_images_are_read(tmp_path):
    values = np.random.default_rng(1).random((4, 6)).astype(np.float32)
    cv2.imwrite(str(tmp_path / "f.pfm"), values)
    np.testing.assert_allclose(load_image(tmp_path / "f.pfm"), values, atol=1e-6)


def test_errors_name_the_file_and_the_problem(tmp_path):
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "junk.png").write_bytes(b"not an image at all")
    with pytest.raises(ImageError, match=r"empty\.png: the file is empty"):
        load_image(tmp_path / "empty.png")
    with pytest.raises(ImageError, match=r"junk\.png: not a readable image"):
        load_image(tmp_path / "junk.png")
    with pytest.raises(ImageError, match="no such file"):
        load_image(tmp_path / "missing.png")
    with pytest.raises(ImageError, match="the file is empty"):
        decode_image(b"", "upload")


def test_pairs_of_different_sizes_are_refused(tmp_path, rgb):
    cv2.imwrite(str(tmp_path / "a.png"), rgb)
    cv2.imwrite(str(tmp_path / "b.png"), rgb[:, :5])
    with pytest.raises(ImageError, match=r"a\.png is 7x5 but .*b\.png is 5x5"):
        load_pair(tmp_path / "a.png", tmp_path / "b.png")


@pytest.mark.parametrize("suffix,tolerance", [(".pfm", 0.0), (".npy", 0.0), (".png", 1 / 512)])
def test_disparity_maps_round_trip(tmp_path, suffix, tolerance):
    disparity = (np.random.default_rng(2).random((9, 11)) * 60).astype(np.float32)
    path = save_disparity(disparity, tmp_path / f"d{suffix}")
    back = load_disparity(path)
    assert back.shape == disparity.shape
    np.testing.assert_allclose(back, disparity, atol=tolerance + 1e-6)


def test_unknown_disparity_extension_is_refused(tmp_path):
    with pytest.raises(ValueError, match="unsupported output extension"):
        save_disparity(np.zeros((2, 2)), tmp_path / "d.jpg")


def test_preview_is_a_colour_png():
    image = cv2.imdecode(
        np.frombuffer(preview_png(np.arange(12.0).reshape(3, 4)), np.uint8), cv2.IMREAD_UNCHANGED
    )
    assert image.shape == (3, 4, 3)
    assert not np.array_equal(image[0, 0], image[2, 3])


def test_png_disparity_never_clips_and_keeps_zero_for_invalid(tmp_path):
    from shared.images import PNG_MAX_DISPARITY, DisparityFormatError

    disparity = np.array([[0.0, 1.5, PNG_MAX_DISPARITY, np.nan]], np.float32)
    save_disparity(disparity, tmp_path / "d.png")
    stored = cv2.imread(str(tmp_path / "d.png"), cv2.IMREAD_UNCHANGED)
    assert stored.tolist() == [[1, 384, 65535, 0]]  # a valid 0 px is not KITTI's invalid 0
    with pytest.raises(DisparityFormatError, match=r"above the 255\.996 px a 16-bit PNG holds"):
        save_disparity(np.array([[256.5]], np.float32), tmp_path / "e.png")
    assert not (tmp_path / "e.png").exists()


def test_match_output_that_a_png_cannot_hold_goes_to_pfm_with_a_warning(tmp_path, capsys):
    from shared.cli import main, save_result

    written = save_result(np.full((2, 2), 300.0, np.float32), str(tmp_path / "d.png"))
    assert written == str(tmp_path / "d.pfm") and (tmp_path / "d.pfm").exists()
    assert "write .pfm or .npy instead: wrote" in capsys.readouterr().err
    view = str(tmp_path / "v.png")
    cv2.imwrite(view, np.zeros((8, 8), np.uint8))
    assert main(["match", view, view, "-o", str(tmp_path / "o.png"), "--max-disparity", "300"]) == 1
    assert "range is 300; write .pfm or .npy" in capsys.readouterr().err
