r"""Image metrics of seed 002 §5.2: PSNR, SSIM, mask IoU (and LPIPS when its weights are available).

* :math:`\mathrm{PSNR} = 10 \log_{10}(\mathrm{MAX}^2 / \mathrm{MSE})`, :math:`\mathrm{MAX} = 1` (images in
  [0, 1]); +inf for identical images.
* SSIM: Wang, Bovik, Sheikh, Simoncelli (2004), Gaussian window :math:`\sigma = 1.5` (truncated at
  :math:`3.5 \sigma`), :math:`K_1 = 0.01`, :math:`K_2 = 0.03`, :math:`L = 1`, averaged over pixels (valid
  region, no padding) and channels. Own numpy/scipy implementation (scikit-image is not a dependency here);
  same constants as ``skimage.metrics.
  structural_similarity(..., gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``.
* :math:`\mathrm{IoU} = |A \cap B| / |A \cup B|` of boolean masks (1 when both are empty); rendered alpha is
  thresholded at 0.5.
* LPIPS needs the backbone (AlexNet/VGG) weights, which are not reachable offline: :func:`lpips` raises
  a clear error when they are missing instead of reporting a number.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from physar.errors import PhysarError


def psnr(a: np.ndarray, b: np.ndarray, max_val: float = 1.0) -> float:
    """Peak signal-to-noise ratio (dB) of two images of the same shape."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise PhysarError(f"psnr: shapes differ {a.shape} vs {b.shape}")
    mse = np.mean((a - b) ** 2)
    return float("inf") if mse == 0 else float(10 * np.log10(max_val**2 / mse))


def ssim(a: np.ndarray, b: np.ndarray, max_val: float = 1.0, sigma: float = 1.5) -> float:
    """Mean structural similarity of two (H, W) or (H, W, C) images (see module docstring)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        raise PhysarError(f"ssim: shapes differ {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    c1, c2 = (0.01 * max_val) ** 2, (0.03 * max_val) ** 2
    trunc = 3.5
    pad = int(trunc * sigma + 0.5)
    vals = []
    for c in range(a.shape[2]):
        x, y = a[..., c], b[..., c]
        f = lambda z: gaussian_filter(z, sigma, truncate=trunc, mode="reflect")
        mx, my = f(x), f(y)
        sxx = f(x * x) - mx * mx
        syy = f(y * y) - my * my
        sxy = f(x * y) - mx * my
        s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
        if s.shape[0] > 2 * pad and s.shape[1] > 2 * pad:
            s = s[pad:-pad, pad:-pad]
        vals.append(s.mean())
    return float(np.mean(vals))


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1.0 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if a.shape != b.shape:
        raise PhysarError(f"iou: shapes differ {a.shape} vs {b.shape}")
    u = np.logical_or(a, b).sum()
    return 1.0 if u == 0 else float(np.logical_and(a, b).sum() / u)


def lpips_model():
    """A callable LPIPS distance :math:`d(a, b)` on (H, W, 3) images in [0, 1] (AlexNet backbone), when the
    ``lpips`` package and its backbone weights are installed; otherwise a PhysarError that says why (the
    ``lpips`` wheel ships only the linear heads, the AlexNet/VGG weights come from torchvision's download
    cache)."""
    try:
        import lpips as _lp
    except ImportError:
        raise PhysarError("LPIPS unavailable: the 'lpips' package is not installed, and its AlexNet/VGG "
                          "backbone weights (not shipped in the wheel) cannot be downloaded offline; "
                          "PSNR, SSIM and IoU are reported instead") from None
    import torch

    try:
        net = _lp.LPIPS(net="alex", verbose=False)
    except Exception as exc:  # noqa: BLE001 - missing torchvision weights: report, do not crash
        raise PhysarError(f"LPIPS unavailable: backbone weights could not be loaded ({exc})") from None
    t = lambda z: torch.as_tensor(np.asarray(z, np.float32)).permute(2, 0, 1)[None] * 2 - 1

    def dist(a: np.ndarray, b: np.ndarray) -> float:
        with torch.no_grad():
            return float(net(t(a), t(b)))

    return dist


def lpips(a: np.ndarray, b: np.ndarray) -> float:
    """LPIPS distance, only when the ``lpips`` package and its backbone weights are installed."""
    return lpips_model()(a, b)


def sequence_metrics(pred_rgb, pred_alpha, gt_rgb, gt_mask, frames, lpips_fn=None, cache: dict | None = None) -> dict:
    """Mean PSNR, SSIM and IoU (and LPIPS when ``lpips_fn`` from :func:`lpips_model` is given) over the listed
    frame indices (NaN for an empty list).

    ``cache``: a dict the caller keeps for one (prediction, truth) pair of sequences; each frame's metrics are
    computed once over the calls that share it (e.g. all frames and their large-deformation subset)."""
    frames = list(frames)
    if not frames:
        out = {"psnr": float("nan"), "ssim": float("nan"), "iou": float("nan"), "frames": 0}
        return out | ({"lpips": float("nan")} if lpips_fn else {})
    cache = {} if cache is None else cache
    for f in frames:
        if f not in cache:
            cache[f] = (psnr(pred_rgb[f], gt_rgb[f]), ssim(pred_rgb[f], gt_rgb[f]),
                        iou(pred_alpha[f] >= 0.5, gt_mask[f] >= 0.5),
                        lpips_fn(pred_rgb[f], gt_rgb[f]) if lpips_fn is not None else None)
    p, s, i, lp = ([cache[f][k] for f in frames] for k in range(4))
    out = {"psnr": float(np.mean(p)), "ssim": float(np.mean(s)), "iou": float(np.mean(i)), "frames": len(frames)}
    if lpips_fn is not None:
        out["lpips"] = float(np.mean(lp))
    return out


def large_deformation_frames(displacement: np.ndarray, frames, fraction: float = 0.5) -> list[int]:
    """Frames of ``frames`` whose ground-truth object displacement is >= ``fraction`` of the maximum over
    ``frames`` themselves (the large-deformation subset of seed Table 1, per evaluated range).

    The threshold is taken over the evaluated frames, not over the whole clip: with the clip maximum (which the
    prediction part reaches) only the last one or two observed frames of the reconstruction range qualified;
    per range, each subset (reconstruction, prediction, novel action) keeps its own most deformed frames."""
    d = np.asarray(displacement)
    frames = list(frames)
    if not frames:
        return []
    thr = fraction * max(float(d[f]) for f in frames)
    return [f for f in frames if d[f] >= thr and d[f] > 0]


__all__ = ["iou", "large_deformation_frames", "lpips", "lpips_model", "psnr", "sequence_metrics", "ssim"]
