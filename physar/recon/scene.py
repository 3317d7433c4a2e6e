"""Scene geometry shared by the synthetic generator and the reconstruction (seed 002, §4.1-4.2, §5.1).

A scene is a body (:class:`physar.skinning.Body`, chosen by ``scene.json`` ``body.model``: ``capsule``, the
procedural capsule humanoid of the synthetic scenes and of scenes written before the field existed; ``anny``, the
default for imported real data; ``smpl:PATH``, a user's SMPL / SMPL-X model file; :func:`load_body`) acting on
a soft object lying on a support (in the synthetic scenes the capsule figure's right forearm presses, squeezes or
lifts it).  World frame: z up, metres.  The MPM domain is the
cube [0, size]^3 of simulation coordinates x_sim = x_world - origin; its face z = 0 is the support.  The
object's canonical (rest) shape is a union of axis-aligned boxes (``scene.json`` field
``object.boxes = [[min, max], ...]``; ``object.min``/``object.max`` are their bounding box, the only fields of a
single-box scene written before the union existed); :func:`object_points` samples it for both the generator
(fine ground truth) and the reconstruction.  The bones listed in ``simulated_bones`` are MPM particles actuated
by the gated PD controller of Eq. (6)-(7) towards their LBS trajectory (Eq. 1); the other bones are rendered
kinematically by LBS only.  A bone's particles are the lattice points inside the body that it owns
(:meth:`physar.skinning.Body.lattice_points`: inside its capsule for the capsule figure, inside the mesh and
nearest to the bone's vertices for a mesh body).  Pose sequences are stored as local joint rotations
(F, B, 3, 3) and a root translation (F, 3) (``poses.npz``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from physar.errors import ConfigError, PhysarError
from physar.skinning import (
    Body,
    CapsuleBody,
    box_distance,  # noqa: F401 - re-exported, the recon modules' historical name
    procedural_humanoid,
)
from physar.skinning import load_body as _load_body

FORMAT_VERSION = 1


def _number(v) -> bool:
    try:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    except OverflowError:  # an integer beyond float range
        return False


def _array(v, shape) -> bool:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return False
    return a.shape == shape and bool(np.all(np.isfinite(a)))


MAX_GRID_RESOLUTION = 256  # MPM cells per side: 256^3 grid nodes already take gigabytes per field

#: scene.json fields the reconstruction reads: (section, key, kind) with kind "pos" (a positive number),
#: "num" (a finite number), "int+" (a positive integer) or an array shape; "?" after the key: optional
_META_FIELDS = (
    ("camera", "fx", "pos"), ("camera", "fy", "pos"), ("camera", "cx", "num"), ("camera", "cy", "num"),
    ("camera", "width", "int+"), ("camera", "height", "int+"), ("camera", "R", (3, 3)), ("camera", "t", (3,)),
    ("sim", "size", "pos"), ("sim", "resolution", "int+"), ("sim", "substeps", "int+"), ("sim", "origin", (3,)),
    ("sim", "gravity", (3,)), ("object", "density", "pos"), ("object", "nu", "num"), ("body", "E", "pos"),
    ("body", "density", "pos"), ("", "fps", "pos"), ("", "n_obs", "int+"), ("", "background?", (3,)),
)


def check_meta(meta: dict, where: str = "scene.json") -> None:
    """One-line ConfigError for the first scene.json field the reconstruction reads that is missing or of the
    wrong type (a number where a number is read, an integer count, a 3-vector, a 3x3 matrix; the object's
    boxes through :func:`object_boxes`), so that a hand-edited or damaged file fails here and not deep inside
    a run."""
    if not isinstance(meta, dict):
        raise ConfigError(f"{where}: must hold a JSON object (a table of fields), got {type(meta).__name__}")
    for sec, key, kind in _META_FIELDS:
        opt = key.endswith("?")
        key = key.rstrip("?")
        d = meta.get(sec) if sec else meta
        name = f"{sec}.{key}" if sec else key
        if sec and not isinstance(d, dict):
            raise ConfigError(f"{where}: field '{sec}' must be a table, got {d!r:.60}")
        if key not in d:
            if opt:
                continue
            raise ConfigError(f"{where}: missing field '{name}'")
        v = d[key]
        ok = (_number(v) and v > 0 if kind == "pos" else _number(v) if kind == "num"
              else _number(v) and isinstance(v, int) and v > 0 if kind == "int+" else _array(v, kind))
        if not ok:
            what = {"pos": "a positive number", "num": "a finite number", "int+": "a positive integer"}.get(
                kind, f"an array of shape {kind}")
            raise ConfigError(f"{where}: field '{name}' must be {what}, got {v!r:.60}")
    if meta["sim"]["resolution"] > MAX_GRID_RESOLUTION:
        raise ConfigError(f"{where}: field 'sim.resolution' must be <= {MAX_GRID_RESOLUTION} cells per side, got "
                          f"{meta['sim']['resolution']}")
    if not isinstance(meta["object"], dict) or ("boxes" not in meta["object"] and "min" not in meta["object"]):
        raise ConfigError(f"{where}: missing field 'object.boxes'")
    try:
        object_boxes(meta)
    except ConfigError as e:  # (a ValueError too: first)
        raise ConfigError(str(e).replace("scene.json", where, 1)) from None
    except (TypeError, ValueError, KeyError):
        raise ConfigError(f"{where}: field 'object.boxes' must be a list of [[x, y, z], [x, y, z]] boxes, got "
                          f"{meta['object'].get('boxes')!r:.60}") from None


def humanoid(height: float) -> CapsuleBody:
    """The procedural capsule figure (float64) of the synthetic scenes."""
    return procedural_humanoid(height, dtype=torch.float64)


def body_model(meta: dict) -> str:
    """``scene.json`` ``body.model``: ``capsule`` when absent (scenes written before the field)."""
    return str(meta["body"].get("model", "capsule"))


def load_body(meta: dict, where: str = "scene.json") -> Body:
    """The scene's body (``body.model``, ``body.height``) as a :class:`physar.skinning.Body`; one-line
    ConfigError naming the field on a bad value."""
    b = meta.get("body")
    if not isinstance(b, dict):
        raise ConfigError(f"{where}: field 'body' must be a table with model and height")
    model, height = b.get("model", "capsule"), b.get("height")
    if not isinstance(height, (int, float)) or isinstance(height, bool):
        raise ConfigError(f"{where}: body.height = {height!r} must be a number (m)")
    try:
        return _load_body(model, float(height), f"{where}: body.model")
    except PhysarError as e:
        raise ConfigError(str(e)) from None


def rot_y(a: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) about +y by angles a (rad)."""
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([c, z, s, z, o, z, -s, z, c], -1).reshape(*a.shape, 3, 3)


def press_poses(body: CapsuleBody, depth: np.ndarray, mode: str = "flat") -> dict:
    """Pose sequence lowering the right forearm by ``depth`` (F,) metres.

    ``flat``: shoulder rotation -a and elbow rotation +a keep the forearm horizontal and lower it by
    L_upper sin a = depth.  ``tilt``: shoulder rotation only, the forearm's midpoint drops by ``depth``
    (a wedge-shaped press).  Returns {"rotations": (F, B, 3, 3), "root_translation": (F, 3)}.
    """
    sk = body.skeleton
    ish, iel = sk.index("upperarm.R"), sk.index("forearm.R")
    heads, tails = body.heads.numpy(), body.tails.numpy()
    depth = np.asarray(depth, dtype=np.float64)
    rots = np.tile(np.eye(3), (len(depth), sk.n_bones, 1, 1))
    if mode == "flat":
        L = np.linalg.norm(heads[iel] - heads[ish])
        a = np.arcsin(np.clip(depth / L, -1, 1))
        rots[:, ish] = rot_y(-a)
        rots[:, iel] = rot_y(a)
    elif mode == "tilt":
        L = np.linalg.norm(0.5 * (heads[iel] + tails[iel]) - heads[ish])
        rots[:, ish] = rot_y(-np.arcsin(np.clip(depth / L, -1, 1)))
    else:
        raise ConfigError(f"press mode '{mode}': use 'flat' or 'tilt'")
    return {"rotations": rots, "root_translation": np.zeros((len(depth), 3))}


def smoothstep(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s * s * (3 - 2 * s)


def check_poses(poses: dict, n_bones: int, name: str = "poses") -> tuple[np.ndarray, np.ndarray]:
    """Validated (rotations (F, B, 3, 3), root translations (F, 3)) from a poses dict/npz."""
    if "rotations" not in poses:
        raise ConfigError(f"{name}: missing array 'rotations' (F, {n_bones}, 3, 3)")
    r = np.asarray(poses["rotations"], dtype=np.float64)
    if r.ndim != 4 or r.shape[1:] != (n_bones, 3, 3) or r.shape[0] < 2:
        raise ConfigError(f"{name}: 'rotations' must have shape (F >= 2, {n_bones}, 3, 3), got {r.shape}")
    t = np.asarray(poses.get("root_translation", np.zeros((len(r), 3))), dtype=np.float64)
    if t.shape != (len(r), 3):
        raise ConfigError(f"{name}: 'root_translation' must have shape ({len(r)}, 3), got {t.shape}")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(t))):
        raise ConfigError(f"{name}: non-finite values")
    err, det = rotation_error(r)
    bad = np.argwhere((err > ROTATION_TOL) | (det < 0))
    if len(bad):  # a scaled or reflected matrix would skin the body inflated or inside out, silently
        f, b = bad[0]
        raise ConfigError(f"{name}: 'rotations' [frame {f}, bone {b}] is not a rotation matrix (|R^T R - I| = "
                          f"{err[f, b]:.3g}, det {det[f, b]:.3g}; expected orthonormal with det +1)")
    return r, t


ROTATION_TOL = 1e-2  # max |R^T R - I| accepted: float32 pose-estimator output passes, a scaled matrix does not


def rotation_error(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r"""Per matrix of ``m`` (..., 3, 3): :math:`\max |R^\top R - I|` and :math:`\det R` (a rotation: 0 and +1)."""
    return np.abs(np.swapaxes(m, -1, -2) @ m - np.eye(3)).max(axis=(-2, -1)), np.linalg.det(m)


def bone_transforms(body: Body, rotations: np.ndarray, root: np.ndarray) -> torch.Tensor:
    """Skinning transforms B_k (F, B, 4, 4) of Eq. 1 for a pose sequence."""
    return body.bone_transforms(torch.as_tensor(rotations, dtype=torch.float64),
                                torch.as_tensor(root, dtype=torch.float64))


def skin_sequence(body: Body, points: np.ndarray, rotations: np.ndarray, root: np.ndarray):
    r"""LBS (Eq. 1) of rest points (N, 3) over a pose sequence: :math:`A^i = \sum_k W_k^i B_k`,
    :math:`\mu^i = A^i_\text{rot} X^i + A^i_t`; positions (F, N, 3) and A_rot (F, N, 3, 3). Dense (capsule) or
    sparse (mesh body: the nearest vertex's weights) skinning weights."""
    X = torch.as_tensor(points, dtype=torch.float64)
    W = body.skinning_weights(X)
    B = bone_transforms(body, rotations, root)  # (F, B, 4, 4)
    if isinstance(W, tuple):
        idx, w = W[0], W[1].double()
        A = torch.stack([(w[..., None, None] * Bf[idx]).sum(-3) for Bf in B]) if len(B) else B[:, :0]
    else:
        A = torch.einsum("nk,fkij->fnij", W.double(), B)
    mu = (A[..., :3, :3] @ X[None, :, :, None])[..., 0] + A[..., :3, 3]
    return mu.numpy(), A[..., :3, :3].numpy()


def reaching_bones(body: Body, rotations: np.ndarray, root: np.ndarray, boxes, margin: float) -> list[str]:
    """Bones whose skinned surface comes within ``margin`` (m) of the object's boxes [(min, max), ...] in some frame
    of the pose sequence (:meth:`physar.skinning.Body.clearance`: the capsule posed rigidly by its own B_k for the
    capsule figure, the bone's own vertices skinned by Eq. 1 for a mesh body): the bones whose LBS impact reaches
    the object (seed 002 §4.2), which the reconstruction simulates and actuates (both hands when both touch).
    Skeleton order."""
    d = body.clearance(bone_transforms(body, rotations, root), boxes)
    return [name for name, dk in zip(body.skeleton.names, d.tolist()) if dk <= margin]


def frame_leaving_domain(body: Body, points: np.ndarray, rotations: np.ndarray, root: np.ndarray,
                         sim: dict) -> int | None:
    """The first frame in which one of the rest ``points`` (N, 3) (a bone's particles), skinned by Eq. 1, lies
    outside the MPM domain ``sim`` (origin, size), or None when they stay inside over the whole sequence. A
    reaching bone that leaves the domain cannot be simulated and stays kinematic."""
    x = skin_sequence(body, points, rotations, root)[0] - np.asarray(sim["origin"], dtype=np.float64)
    out = np.flatnonzero(~np.all((x >= 0) & (x <= sim["size"]), axis=(1, 2)))
    return int(out[0]) if len(out) else None


def domain_side_holding(body: Body, bones: list[str], rotations: np.ndarray, root: np.ndarray, sim: dict,
                        h: float) -> float:
    """The smallest side (m) of a domain with the centre (x, y) and floor z of ``sim``'s that holds the particles of
    ``bones`` over the whole pose sequence (inf when one goes below the floor)."""
    P = body_points(body, bones, h)
    if len(P) == 0:
        return 0.0
    o = np.asarray(sim["origin"], dtype=np.float64)
    x = skin_sequence(body, P, rotations, root)[0] - np.array([o[0] + sim["size"] / 2, o[1] + sim["size"] / 2, o[2]])
    if x[..., 2].min() < 0:
        return math.inf
    return float(max(2 * np.abs(x[..., :2]).max(), x[..., 2].max()))


def simulated_bones(body: Body, meta: dict, rotations: np.ndarray, root: np.ndarray, margin: float,
                    h: float, reaching: list[str] | None = None) -> tuple[list[str], dict[str, int]]:
    """The bones a reconstruction simulates and actuates: those ``meta`` lists plus every bone whose LBS impact
    reaches the object within ``margin`` (:func:`reaching_bones`, or ``reaching`` when the caller has them) and
    whose particles (spacing ``h``) stay in the MPM domain over the clip, in skeleton order; and {reaching bone
    left kinematic: the first frame it leaves the domain}."""
    listed = list(meta["body"].get("simulated_bones", []))
    sim, reach, leaving = meta["sim"], [], {}
    if reaching is None:
        reaching = reaching_bones(body, rotations, root, object_boxes(meta), margin)
    for b in reaching:
        P = body_points(body, [b], h) if b not in listed else None
        if P is not None and len(P) == 0:   # no particle of it at this spacing: nothing to simulate
            continue
        f = None if P is None else frame_leaving_domain(body, P, rotations, root, sim)
        if f is None:
            reach.append(b)
        else:
            leaving[b] = f
    return [b for b in body.skeleton.names if b in listed or b in reach], leaving


def domain_problem(body: Body, meta: dict, leaving: dict[str, int], rotations: np.ndarray, root: np.ndarray,
                   h: float) -> str:
    """One line: no bone can be simulated because the reaching bones ``leaving`` leave the domain, and the
    ``--domain-size`` that would hold them."""
    sim = meta["sim"]
    need = domain_side_holding(body, list(leaving), rotations, root, sim, h)
    hint = (f"import with --domain-size {math.ceil(need * 105) / 100:g} or more" if math.isfinite(need)
            else "they go below the floor: check the up vector")
    o = np.round(np.asarray(sim["origin"], dtype=np.float64), 3).tolist()
    when = ", ".join(f"{b} from frame {f}" for b, f in leaving.items())
    return (f"the bones reaching the object leave the MPM domain, a {sim['size']:g} m cube at {o} ({when} of the "
            f"dynamic clip), so no bone can be simulated: {hint}, or cut the clip to the interaction")


def central_velocities(x: np.ndarray, dt: float) -> np.ndarray:
    """v_n = (x_{n+1} - x_{n-1}) / (2 dt) (seed Eq. 4), one-sided at the ends; x (F, N, 3)."""
    v = np.zeros_like(x)
    if len(x) > 2:
        v[1:-1] = (x[2:] - x[:-2]) / (2 * dt)
    v[0] = (x[1] - x[0]) / dt
    v[-1] = (x[-1] - x[-2]) / dt
    return v


def lattice_box(lo, hi, h: float) -> tuple[np.ndarray, float]:
    """Cell-centred lattice filling the box [lo, hi] with spacing ~h; returns points and the cell volume."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    k = np.maximum(1, np.round((hi - lo) / h)).astype(int)
    step = (hi - lo) / k
    axes = [lo[i] + (np.arange(k[i]) + 0.5) * step[i] for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3), float(np.prod(step))


def body_points(body: Body, bones: list[str], h: float, exclude: list[str] = ()) -> np.ndarray:
    """Rest-pose lattice points (spacing h) of the body owned by ``bones`` and not by ``exclude``
    (:meth:`physar.skinning.Body.lattice_points`)."""
    if not bones:
        return np.zeros((0, 3))
    return body.lattice_points(bones, h, exclude)


capsule_points = body_points  # the name the reconstruction's rig calls


def object_box(meta: dict) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box (min, max) of the object at rest."""
    o = meta["object"]
    return np.asarray(o["min"], dtype=np.float64), np.asarray(o["max"], dtype=np.float64)


def object_boxes(meta: dict) -> list[tuple[np.ndarray, np.ndarray]]:
    """The boxes [(min, max), ...] whose union is the object at rest (one box for old single-box scenes)."""
    o = meta["object"]
    raw = o.get("boxes") or [[o["min"], o["max"]]]
    if not isinstance(raw, list) or not raw:
        raise ConfigError(f"scene.json: object.boxes = {raw!r:.60} must be a non-empty list of [[x, y, z], [x, y, z]]")
    out = []
    for i, b in enumerate(raw):
        if not isinstance(b, list) or len(b) != 2:
            raise ConfigError(f"scene.json: object.boxes[{i}] = {b!r:.60} must be [[x, y, z], [x, y, z]]")
        lo, hi = (np.asarray(v, dtype=np.float64) for v in b)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi) & (hi > lo)):
            raise ConfigError(f"scene.json: object.boxes[{i}] = {b} must be [[x, y, z], [x, y, z]] of finite numbers "
                              "with max > min")
        out.append((lo, hi))
    return out


def union_lattice(boxes, h: float) -> tuple[np.ndarray, float]:
    """Cell-centred lattice points (spacing ~h) inside the union of ``boxes`` [(min, max), ...] and the cell
    volume.  The lattice spans the union's bounding box with per-axis step extent / round(extent / h), so the
    points of one box are exactly :func:`lattice_box`'s, and a union whose faces lie on lattice planes (box
    sizes and offsets multiples of the step) is sampled with count * cell volume = its volume exactly."""
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    P, vol = lattice_box(lo, hi, h)
    keep = np.zeros(len(P), dtype=bool)
    for a, b in boxes:
        keep |= np.all((P >= np.asarray(a)) & (P <= np.asarray(b)), axis=1)
    return P[keep], vol


def object_points(meta: dict, h: float) -> tuple[np.ndarray, float]:
    """Rest-shape particles of the object at spacing ~h (see :func:`union_lattice`) and their cell volume."""
    return union_lattice(object_boxes(meta), h)


def layout(height: float, boxes_local, domain_size: float, rise: float = 0.0, drop: float = 0.0) -> dict:
    """World placement of an object given as boxes [(min, max), ...] in coordinates relative to the midpoint of
    the right forearm's axis at rest (axis along x), and of the MPM domain (x, y centred on the forearm, its
    z = 0 face the object's support).  ``rise``/``drop`` (m): how far the forearm (and, for a lift, the object)
    travels up/down, checked against the domain.  One-line :class:`ConfigError` when something does not fit."""
    body = humanoid(height)
    i = body.skeleton.index("forearm.R")
    a, b, r = body.heads[i].numpy(), body.tails[i].numpy(), float(body.radii[i])
    mid = 0.5 * (a + b)
    boxes = [(mid + np.asarray(lo, float), mid + np.asarray(hi, float)) for lo, hi in boxes_local]
    lo = np.min([x[0] for x in boxes], axis=0)
    hi = np.max([x[1] for x in boxes], axis=0)
    origin = np.array([mid[0] - domain_size / 2, mid[1] - domain_size / 2, lo[2]])
    span = np.abs(b - a)[0] + 2 * r
    size = hi - lo
    if span > domain_size - 0.1 * domain_size or size[:2].max() > 0.8 * domain_size:
        raise ConfigError(f"sim.domain_size = {domain_size} m is too small for the forearm ({span:.2f} m) "
                          f"and the object {tuple(np.round(size, 3))} m")
    top = max(hi[2], mid[2] + r) + rise - origin[2]
    if top > 0.95 * domain_size:
        raise ConfigError(f"sim.domain_size = {domain_size} m is too small: the object/forearm reach "
                          f"{top:.3f} m above the support (object height {size[2]:.3f} m, forearm rise {rise} m)")
    if mid[2] - r - drop - origin[2] < 0:
        raise ConfigError(f"forearm travel down ({drop} m) reaches below the support "
                          f"({mid[2] - r - origin[2]:.3f} m available)")
    return {"object_min": lo, "object_max": hi, "boxes": boxes, "origin": origin, "forearm_mid": mid,
            "forearm_radius": r}


def camera_matrices(meta: dict):
    """(K (3, 3), R (3, 3), t (3,)) of the scene camera (numpy, OpenCV convention)."""
    c = meta["camera"]
    K = np.array([[c["fx"], 0, c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1.0]])
    return K, np.asarray(c["R"], dtype=np.float64), np.asarray(c["t"], dtype=np.float64)


def look_at(eye, target, fov_y_deg: float, width: int, height: int) -> dict:
    """Camera dict (z-up world, image y pointing down) for scene.json."""
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    f = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2)
    return {"fx": f, "fy": f, "cx": width / 2, "cy": height / 2, "width": width, "height": height,
            "R": R.tolist(), "t": (-R @ eye).tolist()}
