"""Static pictures of surfaces (matplotlib, headless): a deformed body coloured by a field."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from physar.geometry.mesh import TriMesh
from physar.output import save_figure


def render_surface(
    surface: TriMesh,
    scalars: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
    label: str = "",
    view: tuple[float, float] = (22.0, -60.0),
    cmap: str = "viridis",
    reference: TriMesh | None = None,
    dpi: int = 130,
) -> Path:
    """Write a PNG of `surface` coloured by per-vertex `scalars`, with a colour bar labelled `label`.

    `reference` (optional) is drawn as a light wireframe (e.g. the undeformed body). Written atomically.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    scalars = np.asarray(scalars, dtype=float)
    tri = surface.points[surface.faces]
    fval = scalars[surface.faces].mean(axis=1)
    norm = matplotlib.colors.Normalize(vmin=float(scalars.min()), vmax=float(scalars.max()) or 1.0)
    colours = matplotlib.colormaps[cmap](norm(fval))
    n = surface.face_normals()
    light = np.array([0.3, -0.5, 0.8])
    shade = 0.55 + 0.45 * np.abs(n @ (light / np.linalg.norm(light)))
    colours[:, :3] *= shade[:, None]

    fig = plt.figure(figsize=(9, 4.2))
    ax = fig.add_subplot(111, projection="3d")
    ax.add_collection3d(Poly3DCollection(tri, facecolors=colours, edgecolors=(0, 0, 0, 0.15), linewidths=0.2))
    pts = surface.points
    if reference is not None:
        e = reference.points[reference.faces][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2, 3)
        ax.add_collection3d(Line3DCollection(e, colors=(0.5, 0.5, 0.5, 0.15), linewidths=0.2))
        pts = np.vstack([pts, reference.points])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    ax.set_xlim(lo[0], hi[0]), ax.set_ylim(lo[1], hi[1]), ax.set_zlim(lo[2], hi[2])
    ext = hi - lo
    ax.set_box_aspect(np.maximum(ext, 0.12 * ext.max()))  # thin bodies stay readable
    for axis, e in zip((ax.xaxis, ax.yaxis, ax.zaxis), ext):
        axis.set_major_locator(matplotlib.ticker.MaxNLocator(6 if e >= 0.5 * ext.max() else 2))
    ax.view_init(*view)
    ax.set_xlabel("x [m]"), ax.set_ylabel("y [m]"), ax.set_zlabel("z [m]")
    sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=ax, shrink=0.7, pad=0.12, label=label)
    ax.set_title(title)
    return save_figure(fig, path, dpi=dpi, bbox_inches="tight")
