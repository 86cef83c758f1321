"""Fitting one image with a coordinate MLP in 2D: how the input encoding sets the kernel width.

Tancik et al. 2020 ("Fourier Features Let Networks Learn High Frequency Functions"): an MLP on raw
coordinates behaves like a very wide kernel (blurry); Gaussian random Fourier features with scale
sigma make the kernel narrower as sigma grows. Too small a sigma still blurs; too large a sigma
makes a kernel narrower than the training pixels' spacing, so the network memorises the training
pixels and fills the pixels between them with noise.

The experiment: train on the even-row, even-column pixels (a 2x subsampled image), score PSNR on
the other three quarters. Every model gets the same seed, steps, learning rate and MLP; only the
encoding differs. Full-batch Adam, MSE on display values in [0, 1].
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Dict, List, Optional, Sequence

import numpy as np
import torch
from torch import nn

from nerf_core.fields.encodings import FourierFeatures, IdentityEncoding, PositionalEncoding

Tensor = torch.Tensor


@dataclass
class FitConfig:
    """What every model in one sweep shares."""

    steps: int = 1000
    lr: float = 1e-3  # Tancik et al.'s 2D image experiments use Adam at 1e-3
    width: int = 128  # 4 x 128 rather than Tancik's 4 x 256: a quarter of the CPU time, same trends
    depth: int = 4  # linear layers, the output layer included
    n_features: int = 128  # Gaussian Fourier features (each gives a sin and a cos)
    seed: int = 0
    threads: Optional[int] = None  # torch threads during the fit; None leaves torch's setting


@dataclass
class EncodingSpec:
    """One model of the sweep: ``kind`` in {"none", "pe", "rff"}; ``sigma`` for rff, ``n_freqs`` for pe."""

    name: str
    kind: str
    sigma: Optional[float] = None
    n_freqs: Optional[int] = None


@dataclass
class FitResult:
    """Scores of one model; ``image`` is its prediction at every pixel (h, w, 3) float32."""

    spec: EncodingSpec
    train_psnr: float
    test_psnr: float
    seconds: float
    params: int
    image: np.ndarray = field(repr=False)

    def as_dict(self) -> Dict:
        return {"name": self.spec.name, "kind": self.spec.kind, "sigma": self.spec.sigma,
                "n_freqs": self.spec.n_freqs, "train_psnr": round(self.train_psnr, 3),
                "test_psnr": round(self.test_psnr, 3), "seconds": round(self.seconds, 2), "params": self.params}


def pixel_coords(h: int, w: int) -> Tensor:
    """(h * w, 2) pixel centres as (x, y) in [0, 1], row-major (the order of ``image.reshape(-1, 3)``)."""
    ys, xs = torch.meshgrid((torch.arange(h) + 0.5) / h, (torch.arange(w) + 0.5) / w, indexing="ij")
    return torch.stack([xs, ys], -1).reshape(-1, 2)


def even_grid_mask(h: int, w: int) -> Tensor:
    """(h * w,) bool, True on the training pixels: even row and even column (a quarter of them)."""
    rows, cols = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    return ((rows % 2 == 0) & (cols % 2 == 0)).reshape(-1)


def nyquist_pe_freqs(h: int, w: int) -> int:
    """Number of NeRF PE frequencies whose highest reaches the training grid's Nyquist rate.

    Frequency k is sin(2^k pi x): 2^(k-1) cycles per unit of x in [0, 1]. The training grid has
    max(h, w) / 2 pixels per unit, so its Nyquist rate is max(h, w) / 4 cycles per unit; the
    highest k with 2^(k-1) <= max(h, w) / 4 gives n_freqs = k + 1.
    """
    return max(1, int(math.floor(math.log2(max(h, w) / 4))) + 2)


def nyquist(h: int, w: int) -> float:
    """The training grid's Nyquist rate in cycles per unit of the [0, 1] coordinates (sigma's unit)."""
    return max(h, w) / 4.0


def default_sweep(sigmas: Sequence[float], pe_freqs: Sequence[int]) -> List[EncodingSpec]:
    """none, one NeRF PE model per frequency count and one Gaussian RFF model per sigma."""
    specs = [EncodingSpec("none", "none")]
    specs += [EncodingSpec(f"pe L={n}", "pe", n_freqs=int(n)) for n in pe_freqs]
    specs += [EncodingSpec(f"rff σ={s:g}", "rff", sigma=float(s)) for s in sigmas]
    return specs


def build_model(spec: EncodingSpec, cfg: FitConfig) -> nn.Module:
    """Encoding + MLP (``cfg.depth`` linear layers of ``cfg.width``, ReLU, sigmoid out): (n, 2) -> (n, 3).

    The MLP's weights come from ``cfg.seed`` (re-seeded here), so models differ only in the encoding
    and in the first layer's input width. RFF's B uses the same seed for every sigma: the same
    directions, scaled.
    """
    if spec.kind == "none":
        enc: nn.Module = IdentityEncoding(2)
    elif spec.kind == "pe":
        enc = PositionalEncoding(2, n_freqs=int(spec.n_freqs or 1))
    elif spec.kind == "rff":
        if not spec.sigma or spec.sigma <= 0:
            raise ValueError(f"{spec.name}: rff needs a positive sigma, got {spec.sigma!r}")
        enc = FourierFeatures(2, cfg.n_features, sigma=spec.sigma, seed=cfg.seed)
    else:
        raise ValueError(f"{spec.name}: unknown encoding kind {spec.kind!r}; choose none, pe or rff")
    torch.manual_seed(cfg.seed)
    layers: List[nn.Module] = [enc]
    dims = [enc.out_dim] + [cfg.width] * (cfg.depth - 1)
    for a, b in zip(dims[:-1], dims[1:]):
        layers += [nn.Linear(a, b), nn.ReLU()]
    layers += [nn.Linear(dims[-1], 3), nn.Sigmoid()]
    return nn.Sequential(*layers)


def psnr(pred: Tensor, target: Tensor) -> float:
    """PSNR in dB of values in [0, 1]; (n, 3) each."""
    mse = float((pred - target).square().mean())
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def fit(image: np.ndarray, spec: EncodingSpec, cfg: FitConfig) -> FitResult:
    """Train one model on ``image`` (h, w, 3) in [0, 1] at the even-even pixels; score the rest."""
    h, w = image.shape[:2]
    coords, target = pixel_coords(h, w), torch.as_tensor(np.ascontiguousarray(image),
                                                         dtype=torch.float32).reshape(-1, 3)
    train = even_grid_mask(h, w)
    x_tr, y_tr = coords[train], target[train]
    old_threads = torch.get_num_threads()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    try:
        model = build_model(spec, cfg)
        opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        start = time.perf_counter()
        for _ in range(cfg.steps):
            loss = (model(x_tr) - y_tr).square().mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        seconds = time.perf_counter() - start
        with torch.no_grad():
            pred = model(coords)
    finally:
        torch.set_num_threads(old_threads)
    params = sum(p.numel() for p in model.parameters())
    return FitResult(spec, psnr(pred[train], y_tr), psnr(pred[~train], target[~train]), seconds, params,
                     pred.reshape(h, w, 3).numpy())


def sweep(image: np.ndarray, specs: Sequence[EncodingSpec], cfg: FitConfig, log=None, jobs: int = 1) -> List[FitResult]:
    """``fit`` for every spec, results in the order of ``specs``; ``log(str)`` as each one finishes.

    ``jobs`` > 1 fits that many models at once in spawned processes, one torch thread each (a small
    MLP gains little from a second thread, and two single-thread fits use two cores fully).
    """
    def report(res: FitResult) -> None:
        if log:
            log(f"{res.spec.name:>12}: train {res.train_psnr:6.2f} dB, held-out {res.test_psnr:6.2f} dB, "
                f"{res.seconds:6.1f} s")

    if jobs <= 1:
        results = []
        for spec in specs:
            results.append(fit(image, spec, cfg))
            report(results[-1])
        return results
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    one_thread = replace(cfg, threads=cfg.threads or 1)
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(fit, image, spec, one_thread): i for i, spec in enumerate(specs)}
        done: Dict[int, FitResult] = {}
        for fut in as_completed(futures):
            done[futures[fut]] = fut.result()
            report(done[futures[fut]])
    return [done[i] for i in range(len(specs))]


def summarize(results: Sequence[FitResult]) -> Dict[str, FitResult]:
    """The models the kernel-width claim is about, picked from a sweep's results.

    Returns {"none", "pe", "best", "too_small", "too_large"} -> FitResult: "pe" is the PE model with
    the highest held-out PSNR (its frequency count is a scale too), "best" the RFF model with the
    highest held-out PSNR, "too_small" / "too_large" the smallest / largest sigma swept.
    """
    def best_of(kind: str) -> Optional[FitResult]:
        same = [r for r in results if r.spec.kind == kind]
        return max(same, key=lambda r: r.test_psnr) if same else None

    rff = sorted((r for r in results if r.spec.kind == "rff"), key=lambda r: r.spec.sigma)
    none, pe = best_of("none"), best_of("pe")
    if not rff or none is None or pe is None:
        raise ValueError("summarize needs a none model, a pe model and at least one rff model")
    return {"none": none, "pe": pe, "best": best_of("rff"), "too_small": rff[0], "too_large": rff[-1]}
