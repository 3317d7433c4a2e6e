r"""Kinematic colliders of the MPM grid update (seed 002, Alg. 1 line "grid velocity update + boundary").

A collider is a rigid box or capsule that moves on a prescribed path (no rotation) and is not affected by the
material.  In the grid update of every substep, each grid node :math:`x_i` that lies inside a collider
(signed distance :math:`\phi(x_i) < 0`) gets the collider's boundary condition in the collider's frame
(Stomakhin et al. 2013, §8; Hu et al. 2018): with the collider velocity :math:`v_c` and the collider's outward
normal :math:`n` at the node, :math:`v_\text{rel} = v_i - v_c` is set by

* sticky: :math:`v_\text{rel} = 0`;
* slip: :math:`v_\text{rel} \leftarrow v_\text{rel} - (v_\text{rel} \cdot n)\, n`, then Coulomb friction on
  the tangential part, with :math:`v_n = v_\text{rel} \cdot n`:

  .. math::

      v_t \leftarrow \begin{cases} 0 & \text{if } \lVert v_t \rVert \le -\mu v_n, \\
      v_t \big(1 + \mu v_n / \lVert v_t \rVert\big) & \text{otherwise;} \end{cases}

* separate: as slip, but only where the node approaches the collider (:math:`v_\text{rel} \cdot n < 0`);

and then :math:`v_i = v_\text{rel} + v_c`.

After G2P, a particle whose new position :math:`x_p` lies inside a collider (at the collider's end-of-substep
position) is projected onto the surface, :math:`x_p \leftarrow x_p - \phi(x_p)\, n(x_p)`, so particles never
penetrate (the grid condition alone lets them sink up to ~0.3 cells into a curved collider).  The coupling of
a body to a sticky or frictional collider acts through the nodes inside it, i.e. through the lowest
layer(s) of a particle's 3x3x3 stencil.

These are the same piecewise-linear maps as the domain walls (:func:`physar.mpm.model._apply_bc`), so the
grid update stays differentiable (almost everywhere) and is taped like the rest of the substep.

Shapes (:math:`c` = centre at time :math:`t`):

* box with half extents :math:`h`: :math:`q = |x - c| - h` (per component),
  :math:`\phi = \lVert \max(q, 0) \rVert + \min(\max_k q_k, 0)`; :math:`n = \nabla \phi`;
* capsule = segment :math:`c \pm L a` (unit axis :math:`a`, half length :math:`L`) swept by a sphere of radius
  :math:`r`:

  .. math::

      s = \operatorname{clamp}\big((x - c) \cdot a, -L, L\big), \qquad
      \phi = \lVert x - c - s a \rVert - r, \qquad n = \frac{x - c - s a}{\lVert x - c - s a \rVert}.

Motion: either a constant velocity, :math:`c(t) = c_0 + u t`, or a keyframed path :math:`(t_k, c_k)`,
piecewise linear, held at the first/last keyframe outside :math:`[t_0, t_K]`.  A substep from :math:`t` to
:math:`t + dt` uses :math:`c(t)` and the mean velocity :math:`(c(t + dt) - c(t)) / dt`, so the material in
contact moves exactly with the collider.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from physar.errors import ConfigError

_f = wp.float64

MAX_COLLIDERS = wp.constant(8)  # colliders per scene (the grid kernel unrolls its collider loop)
SHAPE_BOX, SHAPE_CAPSULE = 0, 1
SHAPE_CODES = {"box": SHAPE_BOX, "capsule": SHAPE_CAPSULE}
COLLIDER_BC = {"sticky": 1, "slip": 2, "separate": 3}


def _vec(v) -> str:
    return "[" + ", ".join(f"{x + 0.0:.4g}" for x in np.asarray(v, dtype=np.float64).ravel().tolist()) + "]"


@dataclass(repr=False)
class Collider:
    """A kinematic box or capsule (SI units).

    ``shape`` "box" (``half_extents`` (3,), m) or "capsule" (``radius`` r and ``half_length`` L of the axis
    segment, along the unit ``axis``); ``center`` the centre at t = 0, ``velocity`` (m/s) for a straight
    motion, or ``path`` (K, 4) keyframes [t, x, y, z] (piecewise-linear; replaces center/velocity);
    ``boundary`` sticky | slip | separate and Coulomb ``friction`` (slip/separate).
    """

    shape: str = "box"
    center: tuple = (0.0, 0.0, 0.0)
    half_extents: tuple = (0.1, 0.1, 0.1)
    radius: float = 0.05
    half_length: float = 0.0
    axis: tuple = (1.0, 0.0, 0.0)
    velocity: tuple = (0.0, 0.0, 0.0)
    path: np.ndarray | None = None
    boundary: str = "separate"
    friction: float = 0.0
    _axis: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        if self.shape not in SHAPE_CODES:
            raise ConfigError(f"collider shape '{self.shape}': choose one of {sorted(SHAPE_CODES)}")
        if self.boundary not in COLLIDER_BC:
            raise ConfigError(f"collider boundary '{self.boundary}': choose one of {sorted(COLLIDER_BC)}")
        if not (self.friction >= 0):
            raise ConfigError(f"collider friction = {self.friction}: must be >= 0")
        if self.shape == "box" and not np.all(np.asarray(self.half_extents, dtype=float) > 0):
            raise ConfigError(f"collider box half extents {self.half_extents} must be positive")
        if self.shape == "capsule" and not (self.radius > 0 and self.half_length >= 0):
            raise ConfigError(f"collider capsule radius {self.radius} must be > 0 and length >= 0")
        a = np.asarray(self.axis, dtype=np.float64)
        if a.shape != (3,) or not np.linalg.norm(a) > 0:
            raise ConfigError(f"collider axis {self.axis} must be a non-zero 3-vector")
        self._axis = a / np.linalg.norm(a)
        if self.path is not None:
            p = np.asarray(self.path, dtype=np.float64)
            if p.ndim != 2 or p.shape[1] != 4 or len(p) < 1 or not np.all(np.isfinite(p)):
                raise ConfigError("collider path must be a list of [t, x, y, z] keyframes")
            if np.any(np.diff(p[:, 0]) <= 0):
                raise ConfigError(f"collider path times {p[:, 0].tolist()} must increase strictly")
            self.path = p

    def __repr__(self) -> str:
        """One line: shape and size [m], motion (centre and velocity, or the keyframes' count and time span),
        boundary and friction (no arrays)."""
        size = (f"half extents {_vec(self.half_extents)} m" if self.shape == "box" else
                f"radius {self.radius:g} m, half length {self.half_length:g} m, axis {_vec(self._axis)}")
        if self.path is None:
            motion = f"center {_vec(self.center)} m, velocity {_vec(self.velocity)} m/s"
        else:
            p = self.path
            motion = f"path of {len(p)} keyframes, t {p[0, 0]:g}..{p[-1, 0]:g} s"
        return f"Collider({self.shape}, {size}, {motion}, {self.boundary}, friction {self.friction:g})"

    def position(self, t: float) -> np.ndarray:
        """Centre c(t) (m)."""
        if self.path is None:
            return np.asarray(self.center, dtype=np.float64) + t * np.asarray(self.velocity, dtype=np.float64)
        p = self.path
        return np.array([np.interp(t, p[:, 0], p[:, k]) for k in (1, 2, 3)])

    def substep_motion(self, t: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(c(t), (c(t + dt) - c(t)) / dt) for a substep from t to t + dt."""
        c0 = self.position(t)
        return c0, (self.position(t + dt) - c0) / dt

    def signed_distance(self, x: np.ndarray, t: float = 0.0) -> np.ndarray:
        r""":math:`\phi(x)` (m) at time t for points x (N, 3); negative inside (NumPy twin of :func:`collider_sdf`)."""
        d = np.asarray(x, dtype=np.float64) - self.position(t)
        if self.shape == "box":
            q = np.abs(d) - np.asarray(self.half_extents, dtype=np.float64)
            return np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)
        s = np.clip(d @ self._axis, -self.half_length, self.half_length)
        return np.linalg.norm(d - s[..., None] * self._axis, axis=-1) - self.radius

    def geometry(self) -> tuple[int, np.ndarray, np.ndarray]:
        """(shape code, size vector, axis) as passed to the kernels: box (hx, hy, hz), capsule (r, L, 0)."""
        if self.shape == "box":
            return SHAPE_BOX, np.asarray(self.half_extents, dtype=np.float64), self._axis
        return SHAPE_CAPSULE, np.array([self.radius, self.half_length, 0.0]), self._axis


@wp.func
def collider_sdf(p: wp.vec3d, kind: wp.int32, c: wp.vec3d, size: wp.vec3d, axis: wp.vec3d) -> wp.vec4d:
    r"""(:math:`\phi`, :math:`n_x`, :math:`n_y`, :math:`n_z`): signed distance of p to the collider and its
    outward normal (module docstring)."""
    d = p - c
    phi = _f(0.0)
    n = wp.vec3d(_f(0.0), _f(0.0), _f(1.0))
    if kind == 0:
        q = wp.vec3d(wp.abs(d[0]) - size[0], wp.abs(d[1]) - size[1], wp.abs(d[2]) - size[2])
        qp = wp.vec3d(wp.max(q[0], _f(0.0)), wp.max(q[1], _f(0.0)), wp.max(q[2], _f(0.0)))
        out = wp.length(qp)
        qmax = wp.max(q[0], wp.max(q[1], q[2]))
        phi = out + wp.min(qmax, _f(0.0))
        sg = wp.vec3d(wp.sign(d[0]), wp.sign(d[1]), wp.sign(d[2]))
        if out > _f(0.0):
            n = wp.cw_mul(sg, qp) / out
        elif q[0] >= q[1] and q[0] >= q[2]:
            n = wp.vec3d(sg[0], _f(0.0), _f(0.0))
        elif q[1] >= q[2]:
            n = wp.vec3d(_f(0.0), sg[1], _f(0.0))
        else:
            n = wp.vec3d(_f(0.0), _f(0.0), sg[2])
    else:
        s = wp.clamp(wp.dot(d, axis), -size[1], size[1])
        r = d - s * axis
        rl = wp.length(r)
        phi = rl - size[0]
        if rl > _f(1.0e-12):
            n = r / rl
    return wp.vec4d(phi, n[0], n[1], n[2])


class ColliderArrays:
    """Per-substep kernel arrays of a list of colliders (all of length max(1, n); ``count`` = n), on the Warp
    ``device`` of the model (:attr:`physar.mpm.model.MPMModel.device`)."""

    def __init__(self, colliders: list[Collider], device: str = "cpu"):
        self.device = device
        self.colliders = list(colliders)
        self.count = len(self.colliders)
        if self.count > MAX_COLLIDERS:
            raise ConfigError(f"{self.count} colliders: at most {MAX_COLLIDERS} are supported")
        k = max(1, self.count)
        geo = [c.geometry() for c in self.colliders]
        self.kind = wp.array([g[0] for g in geo] + [0] * (k - self.count), dtype=wp.int32, device=device)
        pad3 = [np.zeros(3)] * (k - self.count)
        self.size = wp.array(np.array([g[1] for g in geo] + pad3), dtype=wp.vec3d, device=device)
        self.axis = wp.array(np.array([g[2] for g in geo] + pad3), dtype=wp.vec3d, device=device)
        self.bc = wp.array([COLLIDER_BC[c.boundary] for c in self.colliders] + [0] * (k - self.count),
                           dtype=wp.int32, device=device)
        self.friction = wp.array([float(c.friction) for c in self.colliders] + [0.0] * (k - self.count),
                                 dtype=wp.float64, device=device)
        self.center = wp.zeros(k, dtype=wp.vec3d, device=device)
        self.velocity = wp.zeros(k, dtype=wp.vec3d, device=device)
        self._t = None

    def at(self, t: float, dt: float) -> ColliderArrays:
        """Set the centres and velocities of the substep [t, t + dt] (no-op without colliders)."""
        if self.count and self._t != (t, dt):
            mot = [c.substep_motion(t, dt) for c in self.colliders]
            self.center.assign(np.array([m[0] for m in mot]))  # tiny arrays: one row per collider
            self.velocity.assign(np.array([m[1] for m in mot]))
            self._t = (t, dt)
        return self

    def inputs(self) -> list:
        return [self.count, self.kind, self.bc, self.friction, self.center, self.velocity, self.size, self.axis]
