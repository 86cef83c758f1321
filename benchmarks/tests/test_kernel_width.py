"""The kernel-width claim on a real photograph (benchmarks/fourier2d/fit2d.py, benchmarks/fourier2d/photo2d.py).

No encoding blurs; NeRF PE and well-scaled Gaussian Fourier features interpolate held-out pixels;
too small a sigma blurs like no encoding; too large a sigma memorises the training pixels and is
worse than no encoding between them. benchmarks/kernel_width.py draws the same sweep as a chart.
"""
import math
import warnings

import numpy as np
import pytest
import torch

from fourier2d import fit2d
from fourier2d.photo2d import PhotoError, box_downscale, find_hdri, load_photo, synthetic_photo, tonemap

# A 64 px corner of the default crop (fence posts, rocks, leaves), at the HDRI's full resolution.
TEST_CROP = (250, 700, 64)


def test_training_pixels_are_the_even_even_grid():
    mask = fit2d.even_grid_mask(4, 6).reshape(4, 6)
    expected = torch.zeros(4, 6, dtype=torch.bool)
    expected[0, [0, 2, 4]] = expected[2, [0, 2, 4]] = True
    assert torch.equal(mask, expected)
    xy = fit2d.pixel_coords(4, 6).reshape(4, 6, 2)
    # Pixel (row 1, column 2) has its centre at x = 2.5 / 6, y = 1.5 / 4.
    assert torch.allclose(xy[1, 2], torch.tensor([2.5 / 6, 1.5 / 4]))


def test_pe_frequencies_stop_at_the_training_nyquist():
    # 128 px: the training grid has 64 px per unit, Nyquist 32 cycles; sin(2^6 pi x) has 32 cycles.
    assert fit2d.nyquist(128, 128) == 32.0 and fit2d.nyquist_pe_freqs(128, 128) == 7
    assert fit2d.nyquist_pe_freqs(64, 64) == 6 and fit2d.nyquist_pe_freqs(100, 60) == 6  # 2^5/2=16 <= 25 < 32


def test_tonemap_and_downscale_values():
    x = np.array([[0.0, 1.0, 3.0], [-1.0, np.inf, np.nan]], dtype=np.float32)
    expected = [[0.0, 0.5 ** (1 / 2.2), 0.75 ** (1 / 2.2)], [0.0, 0.0, 0.0]]
    assert np.allclose(tonemap(x), expected)
    img = np.arange(16, dtype=np.float32).reshape(4, 4, 1)
    assert np.allclose(box_downscale(img, 2)[..., 0], [[2.5, 4.5], [10.5, 12.5]])


def test_missing_hdri_error_names_the_folder(tmp_path):
    with pytest.raises(PhotoError, match=str(tmp_path / "studiolights" / "world").replace("\\", "\\\\")):
        find_hdri("forest.exr", datafiles=str(tmp_path))


def test_crop_outside_the_image_is_named(tmp_path):
    try:
        path = find_hdri()
    except PhotoError:
        pytest.skip("no bpy studio lights here")
    with pytest.raises(PhotoError, match="does not fit the 1024 x 512 image"):
        load_photo(path, crop=(500, 0, 64))


def _target():
    """The real photograph; a synthetic image with edges and texture only where bpy is absent."""
    try:
        return load_photo(find_hdri(), crop=TEST_CROP, downscale=1)
    except PhotoError as exc:
        warnings.warn(f"kernel-width test uses a SYNTHETIC image, not the photograph: {exc}")
        return synthetic_photo(64)


def test_fourier_feature_scale_sets_the_kernel_width():
    """Measured (forest.exr crop, seed 0, 300 steps, 3 x 128 MLP): held-out none 24.7 dB, PE L=4
    28.2, sigma 0.1 ~25, sigma 3 29.4, sigma 100 21.0 (train 41.9). The margins below are about half
    of the measured gaps."""
    photo = _target()
    cfg = fit2d.FitConfig(steps=300, lr=1e-3, width=128, depth=4, n_features=128, seed=0, threads=1)
    specs = [fit2d.EncodingSpec("none", "none"), fit2d.EncodingSpec("pe", "pe", n_freqs=4),
             *(fit2d.EncodingSpec(f"rff {s:g}", "rff", sigma=s) for s in (0.1, 3.0, 100.0))]
    results = fit2d.sweep(photo.image, specs, cfg, log=print)
    picks = fit2d.summarize(results)
    none, pe, best, small, large = (picks[k] for k in ("none", "pe", "best", "too_small", "too_large"))
    print(f"image: {photo.source}")
    assert best.spec.sigma == 3.0
    # No encoding blurs: PE and the best RFF both beat it on pixels they never saw.
    assert pe.test_psnr >= none.test_psnr + 2.0, (none.test_psnr, pe.test_psnr)
    assert best.test_psnr >= none.test_psnr + 2.5, (none.test_psnr, best.test_psnr)
    # PE and the best RFF land close together.
    assert abs(pe.test_psnr - best.test_psnr) <= 2.0, (pe.test_psnr, best.test_psnr)
    # Too small a sigma: a wide kernel, blurry like no encoding, and it cannot even fit the training
    # pixels much better than the held-out ones.
    assert abs(small.test_psnr - none.test_psnr) <= 1.5, (none.test_psnr, small.test_psnr)
    assert small.train_psnr - small.test_psnr <= 2.0 and small.test_psnr <= best.test_psnr - 2.5
    # Too large a sigma: memorises the training pixels (better than the best sigma there) and is
    # worse than no encoding between them.
    assert large.test_psnr <= none.test_psnr - 1.5, (none.test_psnr, large.test_psnr)
    assert large.train_psnr >= best.train_psnr and large.train_psnr - large.test_psnr >= 10.0
    assert all(math.isfinite(r.test_psnr) for r in results)


def test_script_writes_the_study_and_never_overwrites_it(tmp_path):
    """benchmarks/kernel_width.py end to end on a tiny crop: four files, a JSON whose table matches the
    models asked for, then a refusal to write over them, and a one-line error for a missing EXR."""
    import json
    import subprocess
    import sys

    from nerf_core.tests.conftest import REPO_ROOT

    script = str(REPO_ROOT / "benchmarks" / "kernel_width.py")
    out = tmp_path / "study"
    try:
        find_hdri()
        source = []
    except PhotoError:
        pytest.skip("no bpy studio lights here")
    run = lambda *a: subprocess.run([sys.executable, script, "--out", str(out), *source, *a],  # noqa: E731
                                    capture_output=True, text=True, timeout=300)
    done = run("--crop", "250,700,16", "--steps", "3", "--sigmas", "1,100", "--pe-freqs", "2")
    assert done.returncode == 0, done.stderr
    files = sorted(p.name for p in out.iterdir())
    assert files == ["README.md", "kernel_width.json", "kernel_width.png", "kernel_width_crops.png"]
    data = json.loads((out / "kernel_width.json").read_text())
    assert [r["name"] for r in data["results"]] == ["none", "pe L=2", "rff σ=1", "rff σ=100"]
    assert data["picks"]["too_small"] == "rff σ=1" and data["picks"]["too_large"] == "rff σ=100"
    assert data["image"]["size"] == [16, 16] and data["train_pixels"] == 64 and data["held_out_pixels"] == 192
    assert "| rff σ=100 |" in (out / "README.md").read_text()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    again = run("--steps", "3")
    assert again.returncode == 2 and "already holds" in again.stderr and "Traceback" not in again.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    missing = subprocess.run([sys.executable, script, "--out", str(tmp_path / "x"), "--hdri", str(tmp_path / "no.exr")],
                             capture_output=True, text=True, timeout=300)
    assert missing.returncode == 2 and str(tmp_path / "no.exr") in missing.stderr and "Traceback" not in missing.stderr
    assert not (tmp_path / "x").exists()
    for args, words in ((["--steps", "0"], "--steps 0: must be at least 1"),
                        (["--crop", "0,0,0"], "SIDE must be at least 1 pixel")):
        bad = subprocess.run([sys.executable, script, "--out", str(tmp_path / "y"), *args], capture_output=True,
                             text=True, timeout=300)
        assert bad.returncode == 2 and words in bad.stderr and not (tmp_path / "y").exists()
    corner = subprocess.run([sys.executable, script, "--out", str(tmp_path / "corner"), *source, "--crop", "0,0,8",
                             "--steps", "1", "--sigmas", "1",
                             "--pe-freqs", "1"], capture_output=True, text=True, timeout=300)
    assert corner.returncode == 0, corner.stderr  # an offset of 0 is a crop at the image's corner
