"""Analytic ray caster for textured primitives (ellipsoids, boxes, a room seen from inside).

Vectorised over rays in torch. Rays are cast with *unnormalised* directions whose camera-space z
component is 1, so the ray parameter of a hit is directly its z-depth along the optical axis (the
depth convention of the rasterizer and of ``View`` ground truth).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from moegs.camera import Camera
from moegs.data.synthetic.textures import Texture

KINDS = ("ellipsoid", "box", "room")
_EPS = 1e-4
LIGHT_DIR = (0.35, -0.55, 0.76)  # world, towards the light (z up)
AMBIENT = 0.45


@dataclass
class Primitive:
    """One textured primitive at one time.

    Attributes:
        kind: ``ellipsoid`` (semi-axes ``size``), ``box`` (half-extents ``size``) or ``room`` (a box
            whose inside faces are hit from within).
        center: ``[3]`` world position.
        rotation: ``[3, 3]`` object-to-world rotation (columns are the object axes in world).
        size: ``[3]`` semi-axes / half-extents.
        texture: solid texture evaluated at material coordinates.
        object_id: id of the scene object this part belongs to (1..255).
        material_scale: ``[3]`` factor from local to material coordinates (non-rigid stretching), or None.
        material_offset: ``[3]`` added to material coordinates (distinct texture per part), or None.
        emissive: unlit (colour = albedo).
    """

    kind: str
    center: Tensor
    rotation: Tensor
    size: Tensor
    texture: Texture
    object_id: int
    material_scale: Tensor | None = None
    material_offset: Tensor | None = None
    emissive: bool = False

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"Primitive.kind must be one of {KINDS}, got {self.kind!r}")
        self.center = torch.as_tensor(self.center, dtype=torch.float32).reshape(3)
        self.rotation = torch.as_tensor(self.rotation, dtype=torch.float32).reshape(3, 3)
        self.size = torch.as_tensor(self.size, dtype=torch.float32).reshape(3)
        if (self.size <= 0).any():
            raise ValueError(f"Primitive.size must be positive, got {self.size.tolist()}")
        if not 1 <= self.object_id <= 255:
            raise ValueError(f"Primitive.object_id must be in 1..255, got {self.object_id}")

    def intersect(self, o: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
        """Nearest hit of rays ``o, d [R, 3]`` (world).

        Returns:
            ``t [R]`` (``inf`` on a miss) and the local hit normal ``[R, 3]`` (unnormalised).
        """
        R, c, s = self.rotation.to(o), self.center.to(o), self.size.to(o)
        ol = (o - c) @ R  # R^T (o - c), row-vector form
        dl = d @ R
        inf = torch.full(ol.shape[:1], float("inf"), dtype=o.dtype, device=o.device)
        if self.kind == "ellipsoid":
            os_, ds_ = ol / s, dl / s
            a = (ds_ * ds_).sum(-1)
            b = (os_ * ds_).sum(-1)
            cc = (os_ * os_).sum(-1) - 1.0
            disc = b * b - a * cc
            t0 = (-b - disc.clamp(min=0).sqrt()) / a
            hit = (disc >= 0) & (t0 > _EPS)
            t = torch.where(hit, t0, inf)
            normal = (ol + t0[:, None] * dl) / (s * s)
            return t, normal
        safe = torch.where(dl.abs() < 1e-12, torch.full_like(dl, 1e-12), dl)
        inv = 1.0 / safe
        t1, t2 = (-s - ol) * inv, (s - ol) * inv
        tn, tf = torch.minimum(t1, t2), torch.maximum(t1, t2)
        tnear, axis_near = tn.max(-1)
        tfar, axis_far = tf.min(-1)
        if self.kind == "box":
            hit = (tnear <= tfar) & (tnear > _EPS)
            t, axis = tnear, axis_near
        else:  # room: exit point of a ray starting inside
            hit = (tnear <= tfar) & (tfar > _EPS)
            t, axis = tfar, axis_far
        normal = torch.zeros_like(ol)
        sign = -torch.sign(torch.gather(dl, 1, axis[:, None]))
        normal.scatter_(1, axis[:, None], sign)
        return torch.where(hit, t, inf), normal

    def bounding_radius(self) -> float:
        """Radius of a sphere around ``center`` enclosing the primitive (inf for a room)."""
        if self.kind == "room":
            return float("inf")
        s = self.size
        return float(s.norm()) if self.kind == "box" else float(s.max())

    def material(self, p_world: Tensor) -> Tensor:
        """Material coordinates ``[R, 3]`` of world points ``[R, 3]`` on this primitive."""
        local = (p_world - self.center.to(p_world)) @ self.rotation.to(p_world)
        if self.material_scale is not None:
            local = local * self.material_scale.to(p_world)
        if self.material_offset is not None:
            local = local + self.material_offset.to(p_world)
        return local


@dataclass
class Hits:
    """Per-ray result of ``cast``: z-depth ``t [R]`` (inf: miss), primitive index ``prim [R]`` (-1: miss),
    object id ``ids [R]`` (0: miss) and world normal ``normal [R, 3]``."""

    t: Tensor
    prim: Tensor
    ids: Tensor
    normal: Tensor


def cast(prims: list[Primitive], o: Tensor, d: Tensor) -> Hits:
    """Nearest hit among ``prims`` for rays ``o, d [R, 3]``.

    Each primitive is intersected only with the rays that pass within its bounding sphere.
    """
    n = o.shape[0]
    best = torch.full((n,), float("inf"), dtype=o.dtype, device=o.device)
    prim = torch.full((n,), -1, dtype=torch.int64, device=o.device)
    normal = torch.zeros_like(o)
    dd = (d * d).sum(-1)
    for k, p in enumerate(prims):
        r = p.bounding_radius()
        if r == float("inf"):
            sel = None
            os_, ds_ = o, d
        else:
            oc = o - p.center.to(o)
            b = (oc * d).sum(-1)
            # squared distance from the centre to the ray line, times |d|^2; keep rays ahead of the sphere
            near = ((oc * oc).sum(-1) * dd - b * b <= r * r * dd) & (b < r * dd.sqrt())
            sel = near.nonzero(as_tuple=True)[0]
            if sel.numel() == 0:
                continue
            os_, ds_ = o[sel], d[sel]
        t, nl = p.intersect(os_, ds_)
        nw = nl @ p.rotation.to(o).T
        if sel is None:
            closer = t < best
            best = torch.where(closer, t, best)
            prim = torch.where(closer, torch.full_like(prim, k), prim)
            normal = torch.where(closer[:, None], nw, normal)
        else:
            closer = t < best[sel]
            idx = sel[closer]
            best[idx] = t[closer]
            prim[idx] = k
            normal[idx] = nw[closer]
    normal = torch.nn.functional.normalize(normal, dim=-1)
    id_table = torch.tensor([0] + [p.object_id for p in prims], dtype=torch.int64, device=o.device)
    return Hits(t=best, prim=prim, ids=id_table[prim + 1], normal=normal)


def shade(prims: list[Primitive], hits: Hits, o: Tensor, d: Tensor, time: float) -> Tensor:
    """Lambertian colour ``[R, 3]`` of the hits (0 on a miss)."""
    rgb = torch.zeros_like(o)
    light = torch.nn.functional.normalize(torch.tensor(LIGHT_DIR, dtype=o.dtype, device=o.device), dim=0)
    for k, p in enumerate(prims):
        sel = (hits.prim == k).nonzero(as_tuple=True)[0]
        if sel.numel() == 0:
            continue
        pw = o[sel] + hits.t[sel, None] * d[sel]
        albedo = p.texture(p.material(pw), time)
        if p.emissive:
            col = albedo
        else:
            lam = (hits.normal[sel] @ light).clamp(min=0.0)
            col = albedo * (AMBIENT + (1.0 - AMBIENT) * lam)[:, None]
        rgb[sel] = col
    return rgb


def camera_rays(
    camera: Camera, offsets: Tensor | None = None, dtype: torch.dtype = torch.float32
) -> tuple[Tensor, Tensor]:
    """Rays through sub-pixel positions.

    Args:
        camera: pinhole camera (OpenCV).
        offsets: ``[S, 2]`` sub-pixel offsets in [0, 1) (default the pixel centre ``(0.5, 0.5)``).
    Returns:
        origins ``[S, H, W, 3]`` and directions ``[S, H, W, 3]`` scaled so that their camera-space z is 1.
    """
    if offsets is None:
        offsets = torch.tensor([[0.5, 0.5]], dtype=dtype)
    H, W = camera.height, camera.width
    K = camera.K.to(dtype)
    w2c = camera.world_to_camera.to(dtype)
    dev = camera.K.device
    ys, xs = torch.meshgrid(
        torch.arange(H, dtype=dtype, device=dev), torch.arange(W, dtype=dtype, device=dev), indexing="ij"
    )
    offsets = offsets.to(device=dev, dtype=dtype)
    u = xs[None] + offsets[:, 0, None, None]
    v = ys[None] + offsets[:, 1, None, None]
    x = (u - K[0, 2] - K[0, 1] * (v - K[1, 2]) / K[1, 1]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    dirs_cam = torch.stack([x, y, torch.ones_like(x)], dim=-1)
    R, tvec = w2c[:3, :3], w2c[:3, 3]
    dirs = dirs_cam @ R  # R^T d
    center = -R.T @ tvec
    return center.expand_as(dirs), dirs


def subpixel_offsets(n: int) -> Tensor:
    """``[n*n, 2]`` stratified sub-pixel offsets (regular grid)."""
    g = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    yy, xx = torch.meshgrid(g, g, indexing="ij")
    return torch.stack([xx.reshape(-1), yy.reshape(-1)], dim=-1)


@dataclass
class Render:
    """Output of ``render``.

    Attributes:
        rgb: ``[H, W, 3]`` straight (not premultiplied) colour in [0, 1]; 0 where nothing is hit.
        alpha: ``[H, W]`` coverage in [0, 1] (fraction of sub-pixel rays that hit a surface).
        depth: ``[H, W]`` z-depth of the pixel-centre ray, 0 where it hits nothing.
        ids: ``[H, W]`` int64 object id hit by the pixel-centre ray, 0 where nothing.
        normal: ``[H, W, 3]`` world normal at the pixel-centre hit.
    """

    rgb: Tensor
    alpha: Tensor
    depth: Tensor
    ids: Tensor
    normal: Tensor = field(repr=False)


@torch.no_grad()
def render(
    prims: list[Primitive], camera: Camera, time: float, supersample: int = 1, chunk: int = 1 << 17
) -> Render:
    """Ray-cast ``prims`` (already posed at ``time``) from ``camera``.

    Colour and alpha average ``supersample**2`` stratified rays per pixel; depth, ids and normals
    come from the single pixel-centre ray (exact geometric ground truth, no mixing at edges).
    """
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    H, W = camera.height, camera.width

    def run(o: Tensor, d: Tensor, with_color: bool) -> tuple[Hits, Tensor | None]:
        parts, cols = [], []
        for s in range(0, o.shape[0], chunk):
            h = cast(prims, o[s : s + chunk], d[s : s + chunk])
            parts.append(h)
            if with_color:
                cols.append(shade(prims, h, o[s : s + chunk], d[s : s + chunk], time))
        hits = Hits(*(torch.cat([getattr(h, f) for h in parts]) for f in ("t", "prim", "ids", "normal")))
        return hits, (torch.cat(cols) if with_color else None)

    oc, dc = camera_rays(camera)
    centre, centre_rgb = run(oc.reshape(-1, 3), dc.reshape(-1, 3), with_color=supersample == 1)
    if supersample == 1:
        rgb = centre_rgb
        cover = (centre.prim >= 0).to(rgb.dtype)
    else:
        os_, ds_ = camera_rays(camera, subpixel_offsets(supersample))
        S = os_.shape[0]
        hits, col = run(os_.reshape(-1, 3), ds_.reshape(-1, 3), with_color=True)
        hit = (hits.prim >= 0).to(col.dtype).reshape(S, H * W)
        col = col.reshape(S, H * W, 3)
        cover = hit.mean(0)
        rgb = (col * hit[..., None]).sum(0) / hit.sum(0).clamp(min=1.0)[:, None]
    hit_c = centre.prim >= 0
    depth = torch.where(hit_c, centre.t, torch.zeros_like(centre.t))
    return Render(
        rgb=rgb.reshape(H, W, 3).clamp(0.0, 1.0),
        alpha=cover.reshape(H, W),
        depth=depth.reshape(H, W),
        ids=centre.ids.reshape(H, W),
        normal=centre.normal.reshape(H, W, 3),
    )
