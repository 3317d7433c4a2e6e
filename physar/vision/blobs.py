"""Printed dots found near their predicted pixels, in any light (seed 000 §2.1: tracked points on the object).

The search is brightness-invariant: for a saturated dot colour the score of a pixel is how close its
chromaticity c = BGR / (B + G + R) is to the dot's, relative to grey (1 at the dot's colour, 0 at grey), so
that dimming the light, shading and vignetting (which scale B, G and R together) do not change it; for a
grey-ish dot colour (black or white dots) the score is the luma contrast to the window's border. The
threshold is adaptive: halfway between the window's background (median of its border) and the peak next to
the prediction. The dot's position is the centroid of its luma contrast above half the peak inside the
(dilated) colour mask: video stores colour at half resolution (4:2:0), so a chroma centroid would lock to
the 2-pixel chroma grid, while luma has full resolution.
"""
from __future__ import annotations

import numpy as np

from physar.vision.dots import DotTracker


def _windows(img, centres, k):
    """(n, 2k+1, 2k+1, ...) windows of img around integer centres (n, 2) (clipped to the image) and their
    pixel coordinates (ys, xs), each (n, 2k+1, 2k+1)."""
    h, w = img.shape[:2]
    cx = np.clip(centres[:, 0], k, w - k - 1)
    cy = np.clip(centres[:, 1], k, h - k - 1)
    o = np.arange(-k, k + 1)
    ys = cy[:, None, None] + o[None, :, None]
    xs = cx[:, None, None] + o[None, None, :]
    ys, xs = np.broadcast_arrays(ys, xs)
    win = np.stack([img[y - k:y + k + 1, x - k:x + k + 1] for x, y in zip(cx.tolist(), cy.tolist())]) \
        if len(cx) else img[ys, xs]       # slices: a gather by index arrays is several times slower
    return win, ys, xs


def dot_score(win_bgr: np.ndarray, colour_rgb) -> np.ndarray:
    """Score in [.., 1] of each pixel of BGR windows (n, k, k, 3) being the dot colour (see module doc)."""
    bgr = np.asarray(colour_rgb, float)[::-1]
    x = [win_bgr[..., i].astype(np.float32) for i in range(3)]   # channel by channel: numpy reduces a last
    s = x[0] + x[1] + x[2]                                       # axis of length 3 slowly
    target = bgr / max(bgr.sum(), 1.0)
    if np.ptp(bgr) < 40:  # grey-ish dot: luma contrast (sign: darker or brighter than grey 128)
        sign = -1.0 if bgr.mean() < 128 else 1.0
        return sign * s / (3 * 255.0)
    # |c - target| with c = x / S, S = max(B + G + R, 24), as |x - S target| / S
    S = np.maximum(s, np.float32(24.0))
    d2 = sum((xi - S * np.float32(ti)) ** 2 for xi, ti in zip(x, target))
    grey = np.full(3, 1 / 3)
    return 1.0 - np.sqrt(d2) / (S * np.float32(np.linalg.norm(grey - target)))


def find_dots(frame, gray, pred, radius_px, colour_rgb, search_px, min_contrast: float = 0.15):
    r"""Centroids (n, 2) [px] and validity (n,) of the dots predicted at ``pred`` (n, 2) with expected image
    radius ``radius_px`` (n,) [px], searched within ``search_px`` (n,) of the prediction.

    A dot is valid when its peak score exceeds the window's background by ``min_contrast`` and its mask's
    area is within 0.25-4 times the expected :math:`\pi r^2`."""
    pred = np.asarray(pred, float)
    n = len(pred)
    out = np.full((n, 2), np.nan)
    valid = np.zeros(n, bool)
    if n == 0:
        return out, valid
    h, w = frame.shape[:2]
    r = np.maximum(np.asarray(radius_px, float), 1.0)
    inside = np.all(np.isfinite(pred), 1) & (pred[:, 0] > 2) & (pred[:, 1] > 2) & (pred[:, 0] < w - 3) \
        & (pred[:, 1] < h - 3)
    if not inside.any():
        return out, valid
    idx = np.flatnonzero(inside)
    search = np.asarray(search_px, float)[idx]
    k = int(min(np.ceil(np.max(search + 2 * r[idx])), min(h, w) // 2 - 1))
    ctr = np.round(pred[idx]).astype(int)
    win, ys, xs = _windows(frame, ctr, k)
    sc = dot_score(win, colour_rgb)
    border = np.concatenate([sc[:, 0, :], sc[:, -1, :], sc[:, :, 0], sc[:, :, -1]], 1)
    bg = np.median(border, 1)
    d2 = (xs - pred[idx, 0, None, None]) ** 2 + (ys - pred[idx, 1, None, None]) ** 2
    near = d2 <= (search + r[idx])[:, None, None] ** 2
    # the peak next to the prediction: score weighted down with distance
    wsc = np.where(near, sc - 0.5 * np.sqrt(d2) / np.maximum(search + r[idx], 1)[:, None, None] * 0.2, -np.inf)
    flat = wsc.reshape(len(idx), -1).argmax(1)
    peak = sc.reshape(len(idx), -1)[np.arange(len(idx)), flat]
    ok = peak - bg > min_contrast
    px0 = np.column_stack([xs.reshape(len(idx), -1)[np.arange(len(idx)), flat],
                           ys.reshape(len(idx), -1)[np.arange(len(idx)), flat]])
    # second pass: a window around the peak, radius 2 r
    m = int(min(np.ceil(2.2 * r[idx].max()) + 2, min(h, w) // 2 - 1))
    win2, ys2, xs2 = _windows(frame, px0, m)
    s2 = dot_score(win2, colour_rgb)
    thr = 0.5 * (peak + bg)
    mask = s2 > thr[:, None, None]
    dd = (xs2 - px0[:, 0, None, None]) ** 2 + (ys2 - px0[:, 1, None, None]) ** 2
    mask &= dd <= (1.8 * r[idx])[:, None, None] ** 2
    area = mask.sum((1, 2))
    exp_area = np.pi * r[idx] ** 2
    ok &= (area >= 0.25 * exp_area) & (area <= 4 * exp_area)
    if gray is not None:
        g = gray[ys2, xs2].astype(np.float32)
        sup = DotTracker._dilate(mask, 1)
        gb = np.concatenate([g[:, 0, :], g[:, -1, :], g[:, :, 0], g[:, :, -1]], 1)
        dg = g - np.median(gb, 1)[:, None, None]
        sign = np.sign(np.where(mask, dg, 0.0).sum((1, 2)))
        dg = sign[:, None, None] * dg * sup
        pk = dg.max((1, 2))[:, None, None]
        wgt = np.maximum(dg - 0.5 * pk, 0.0)
        use_luma = (wgt.sum((1, 2)) > 0) & (pk.ravel() > 2.0)
        wcol = np.maximum(s2 - thr[:, None, None], 0) * mask
        wgt = np.where(use_luma[:, None, None], wgt, wcol)
    else:
        wgt = np.maximum(s2 - thr[:, None, None], 0) * mask
    msum = wgt.sum((1, 2))
    ok &= msum > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        cen = np.column_stack([(wgt * xs2).sum((1, 2)) / msum, (wgt * ys2).sum((1, 2)) / msum])
    ok &= np.linalg.norm(cen - pred[idx], axis=1) <= search + r[idx]
    out[idx[ok]] = cen[ok]
    valid[idx[ok]] = True
    return out, valid


__all__ = ["dot_score", "find_dots"]
