r"""Image metrics of seed 002 §5.2: PSNR, SSIM, mask IoU (and LPIPS when its weights are available).

* :math:`\mathrm{PSNR} = 10 \log_{10}(\mathrm{MAX}^2 / \mathrm{MSE})`; +inf for identical images.
* SSIM: Wang, Bovik, Sheikh, Simoncelli (2004), Gaussian window :math:`\sigma = 1.5` (truncated at
  :math:`3.5 \sigma`), :math:`K_1 = 0.01`, :math:`K_2 = 0.03`, :math:`L = \mathrm{MAX}`, averaged over pixels
  (valid region, no padding) and channels.
* MAX (``max_val``) as ``skimage.metrics`` infers its ``data_range`` from the dtype when it is not given:
  float images are in [0, 1] (MAX = 1), unsigned-integer images span their dtype (uint8: 0..255, MAX = 255;
  uint16: MAX = 65535). Unlike skimage, which warns and uses the first image's dtype, a float image compared
  with an integer one (or two integer dtypes) is refused without an explicit ``max_val``, and signed-integer
  or boolean images need one too (an ``int64`` array of 0..255 values would otherwise get MAX = 2^63 - 1).
  With an explicit ``max_val`` both images must be on that scale. Own numpy/scipy implementation (scikit-image is not a dependency here);
  same constants as ``skimage.metrics.
  structural_similarity(..., gaussian_weights=True, sigma=1.5, use_sample_covariance=False)``.
* :math:`\mathrm{IoU} = |A \cap B| / |A \cup B|` of boolean masks (1 when both are empty); rendered alpha is
  thresholded at 0.5 by :func:`sequence_metrics`. :func:`iou` itself takes boolean masks or arrays of 0 and 1
  only, and refuses other values (a soft alpha in [0, 1] cast to bool would count every non-zero pixel).
* LPIPS needs the backbone (AlexNet/VGG) weights, which are not reachable offline: :func:`lpips` raises
  a clear error when they are missing instead of reporting a number.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from physar.errors import ConfigError, PhysarError


def _max_val(name: str, a: np.ndarray, b: np.ndarray, max_val: float | None) -> float:
    """MAX of two images (module docstring): ``max_val`` when given (finite, > 0), else from their dtypes."""
    if max_val is not None:
        try:
            if isinstance(max_val, (str, bytes, bool)):
                raise TypeError
            max_val = float(max_val)
        except (TypeError, ValueError):
            raise ConfigError(f"{name}: max_val = {max_val!r} must be a number (e.g. 255 or 1.0)") from None
        if not (np.isfinite(max_val) and max_val > 0):
            raise ConfigError(f"{name}: max_val = {max_val!r} must be a finite number > 0")
        a_int, b_int = np.issubdtype(a.dtype, np.integer), np.issubdtype(b.dtype, np.integer)
        if a_int != b_int:
            raise ConfigError(f"{name}: a is {a.dtype} but b is {b.dtype}: give both images on one scale "
                              f"(e.g. a float image * 255 as uint8, or both as float in [0, 1])")
        return float(max_val)
    kinds = {a.dtype.kind, b.dtype.kind}
    if kinds <= {"f"}:
        top = max((float(np.nanmax(np.abs(x))) for x in (a, b) if x.size), default=0.0)
        if top > 2.0:  # renders overshoot 1 a little; 0..255 data taken as [0, 1] gave PSNRs off by 48 dB
            raise ConfigError(f"{name}: float images are taken in [0, 1], but values reach {top:g}: pass "
                              f"max_val (e.g. 255 for 0..255 data) or scale them")
        return 1.0
    if kinds == {"u"} and a.dtype == b.dtype:
        return float(np.iinfo(a.dtype).max)
    if "f" in kinds and kinds & {"u", "i"}:
        raise ConfigError(f"{name}: a is {a.dtype} but b is {b.dtype}: a float image is taken in [0, 1] and "
                          f"an integer one in 0..max of its dtype; convert one (e.g. uint8 / 255.0) or pass max_val")
    raise ConfigError(f"{name}: cannot infer the value range of images of dtype {a.dtype} and {b.dtype} "
                      f"(float: [0, 1], one unsigned-integer dtype: 0..its max); pass max_val (e.g. 255)")


def _images(name: str, a, b, max_val: float | None) -> tuple[np.ndarray, np.ndarray, float]:
    """(a, b) as float64 arrays of one shape and their MAX (:func:`_max_val`)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        raise ConfigError(f"{name}: shapes differ {a.shape} vs {b.shape}")
    peak = _max_val(name, a, b, max_val)
    return a.astype(np.float64), b.astype(np.float64), peak


def psnr(a: np.ndarray, b: np.ndarray, max_val: float | None = None) -> float:
    """Peak signal-to-noise ratio (dB) of two images of the same shape; ``max_val`` (MAX) by default from the
    dtype: 1 for float images in [0, 1], 255 for uint8, 65535 for uint16 (module docstring)."""
    a, b, peak = _images("psnr", a, b, max_val)
    mse = np.mean((a - b) ** 2)
    return float("inf") if mse == 0 else float(10 * np.log10(peak**2 / mse))


def ssim(a: np.ndarray, b: np.ndarray, max_val: float | None = None, sigma: float = 1.5) -> float:
    """Mean structural similarity of two (H, W) or (H, W, C) images (see module docstring; ``max_val`` as in
    :func:`psnr`)."""
    a, b, peak = _images("ssim", a, b, max_val)
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    c1, c2 = (0.01 * peak) ** 2, (0.03 * peak) ** 2
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


def _mask(name: str, arg: str, m) -> np.ndarray:
    """``m`` as a boolean mask: a bool array, or a numeric one holding 0 and at most one other value (0/1,
    0/255 as OpenCV and PNG masks hold), True where it is not 0; else (a soft alpha, a label image, NaN) a
    ConfigError."""
    m = np.asarray(m)
    if m.dtype == bool:
        return m
    ok = m.dtype.kind in "uif"
    if ok:
        on = m[m != 0]
        ok = bool(np.isfinite(on).all()) and (on.size == 0 or bool(np.all(on == on.flat[0])))
    if not ok:
        lo, hi = (float(np.nanmin(m)), float(np.nanmax(m))) if m.size and m.dtype.kind in "uif" else (None, None)
        rng = f" values in [{lo:g}, {hi:g}]" if lo is not None else ""
        raise ConfigError(f"{name}: {arg} must be a boolean mask or hold 0 and one other value, e.g. 0/1 or 0/255 "
                          f"(got {m.dtype}{rng}); threshold it first, e.g. {arg} >= 0.5")
    return m != 0


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks, or arrays of 0 and one other value (0/1, 0/255), 1.0 when
    both are empty; anything else (a soft alpha, a label image) is refused: threshold it first."""
    a, b = _mask("iou", "a", a), _mask("iou", "b", b)
    if a.shape != b.shape:
        raise ConfigError(f"iou: shapes differ {a.shape} vs {b.shape}")
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
