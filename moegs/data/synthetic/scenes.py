"""Procedural dynamic scenes: objects with analytic motion, visibility and appearance over t in [0, 1].

Each named scene mixes the motion regimes that MoE-GS / MoDE argue favour different deformation
models (static background, smooth rigid motion, fast articulated motion, non-rigid pulsation, abrupt
irregular motion, transient objects, appearance change). World frame: z up, metres.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

from moegs.data.synthetic.raycast import Primitive
from moegs.data.synthetic.textures import Texture

CATEGORIES = ("static", "rigid_smooth", "articulated", "nonrigid", "abrupt", "transient", "appearance")


def rot_z(a: float) -> Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(a: float) -> Tensor:
    c, s = math.cos(a), math.sin(a)
    return torch.tensor([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _segment_frame(direction: Tensor) -> Tensor:
    """Rotation whose x axis is ``direction`` (unit, in the world x-z plane) and y axis is world y."""
    x = direction / direction.norm()
    y = torch.tensor([0.0, 1.0, 0.0])
    z = torch.linalg.cross(x, y)
    return torch.stack([x, y, z], dim=1)


def _always(_t: float) -> bool:
    return True


@dataclass(frozen=True)
class SceneObject:
    """One object of a synthetic scene.

    Attributes:
        name: unique name (``room``, ``cube``, ``arm`` ...).
        object_id: id written in the ground-truth id maps (1..255; 0 means no surface).
        category: one of ``CATEGORIES``.
        description: human-readable motion description (copied to ``scene_meta.json``).
        parts: ``t -> list[Primitive]`` posed primitives at ``t`` (empty when the object is absent).
        position: ``t -> [3]`` reference point of the object (for trajectories / velocity checks).
        visible: ``t -> bool``.
    """

    name: str
    object_id: int
    category: str
    description: str
    parts: Callable[[float], list[Primitive]] = field(repr=False)
    position: Callable[[float], Tensor] = field(repr=False)
    visible: Callable[[float], bool] = field(default=_always, repr=False)

    def __post_init__(self) -> None:
        if self.category not in CATEGORIES:
            raise ValueError(f"category must be one of {CATEGORIES}, got {self.category!r}")

    @property
    def dynamic(self) -> bool:
        """Everything but ``static`` changes over time (geometry, visibility or appearance)."""
        return self.category != "static"

    def velocity(self, t: float, h: float = 1e-4) -> Tensor:
        """Finite-difference velocity ``[3]`` of ``position`` at ``t`` (forward; backward at t = 1)."""
        if t + h <= 1.0:
            return (self.position(t + h) - self.position(t)) / h
        return (self.position(t) - self.position(t - h)) / h


@dataclass
class SceneDescription:
    """A named procedural scene.

    Attributes:
        name: scene name (``n3v_like`` | ``dnerf_like``).
        seed: generation seed.
        objects: the objects, ids 1..K in order.
        bbox: ``[2, 3]`` bounds of the content seen by the cameras.
        target: ``[3]`` point the camera rigs look at.
        closed: True when a room surrounds the content (every ray hits a surface).
    """

    name: str
    seed: int
    objects: list[SceneObject]
    bbox: Tensor
    target: Tensor
    closed: bool

    def __post_init__(self) -> None:
        ids = [o.object_id for o in self.objects]
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate object ids in scene {self.name!r}: {ids}")

    def primitives(self, t: float) -> list[Primitive]:
        """All posed primitives at time ``t``."""
        out: list[Primitive] = []
        for o in self.objects:
            if o.visible(t):
                out.extend(o.parts(t))
        return out

    def object(self, name: str) -> SceneObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(
            f"scene {self.name!r} has no object {name!r}; objects: {[o.name for o in self.objects]}"
        )

    def dynamic_ids(self) -> list[int]:
        return [o.object_id for o in self.objects if o.dynamic]

    def id_to_dynamic(self) -> Tensor:
        """``[256]`` bool lookup table: id -> whether the object is dynamic (id 0 -> False)."""
        lut = torch.zeros(256, dtype=torch.bool)
        lut[self.dynamic_ids()] = True
        return lut

    def table(self) -> list[dict]:
        """JSON-ready description of the objects."""
        return [
            {
                "id": o.object_id,
                "name": o.name,
                "category": o.category,
                "dynamic": o.dynamic,
                "description": o.description,
            }
            for o in self.objects
        ]


# -- building blocks --------------------------------------------------------------------------------


def _static(
    name: str, oid: int, kind: str, center, size, tex: Texture, desc: str, rotation: Tensor | None = None
) -> SceneObject:
    c = torch.tensor(center, dtype=torch.float32)
    R = torch.eye(3) if rotation is None else rotation
    prim = Primitive(kind, c, R, torch.tensor(size, dtype=torch.float32), tex, oid)
    return SceneObject(name, oid, "static", desc, parts=lambda t: [prim], position=lambda t: c.clone())


def _smooth_cube(
    oid: int, path: Callable[[float], tuple[Tensor, float]], half: float, tex: Texture, desc: str
) -> SceneObject:
    def parts(t: float) -> list[Primitive]:
        c, yaw = path(t)
        return [Primitive("box", c, rot_z(yaw), torch.full((3,), half), tex, oid)]

    return SceneObject("cube", oid, "rigid_smooth", desc, parts=parts, position=lambda t: path(t)[0])


def _arm(
    oid: int,
    shoulder: Tensor,
    lengths: tuple[float, float],
    thick: float,
    cycles: float,
    phase: float,
    tex: Texture,
    desc: str,
    swing: float = 1.0,
    hand: float = 0.1,
) -> SceneObject:
    """Two box segments and a spherical hand (radius ``hand``) swinging in the world x-z plane: shoulder
    angle ``0.85 swing sin(w)``, elbow ``0.9 + 0.75 swing sin(w + 1.3)``, ``w = 2 pi cycles t + phase``."""
    L1, L2 = lengths

    def angles(t: float) -> tuple[float, float]:
        w = 2.0 * math.pi * cycles * t + phase
        a1 = 0.85 * swing * math.sin(w)
        a2 = a1 + 0.9 + 0.75 * swing * math.sin(w + 1.3)
        return a1, a2

    def joints(t: float) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        a1, a2 = angles(t)
        u1 = torch.tensor([math.sin(a1), 0.0, -math.cos(a1)])
        u2 = torch.tensor([math.sin(a2), 0.0, -math.cos(a2)])
        elbow = shoulder + L1 * u1
        wrist = elbow + L2 * u2
        return u1, u2, elbow, wrist, shoulder

    def parts(t: float) -> list[Primitive]:
        u1, u2, elbow, wrist, sh = joints(t)
        return [
            Primitive(
                "box", sh + 0.5 * L1 * u1, _segment_frame(u1), torch.tensor([L1 / 2, thick, thick]), tex, oid
            ),
            Primitive(
                "box",
                elbow + 0.5 * L2 * u2,
                _segment_frame(u2),
                torch.tensor([L2 / 2, thick * 0.85, thick * 0.85]),
                tex,
                oid,
                material_offset=torch.tensor([3.0, 0.0, 0.0]),
            ),
            Primitive(
                "ellipsoid",
                wrist + 0.8 * hand * u2,
                _segment_frame(u2),
                torch.full((3,), hand),
                tex,
                oid,
                material_offset=torch.tensor([6.0, 0.0, 0.0]),
            ),
        ]

    return SceneObject("arm", oid, "articulated", desc, parts=parts, position=lambda t: joints(t)[3])


def _blob(
    oid: int, base: Tensor, r0: float, cycles: float, tex: Texture, desc: str, squash: float = 0.25
) -> SceneObject:
    """Ellipsoid that squashes and stretches (volume-changing, non-rigid) while resting on ``base``: its
    horizontal semi-axes grow by ``squash`` and its height shrinks by ``1.2 squash`` at the peak."""

    def axes(t: float) -> Tensor:
        s = squash * math.sin(2.0 * math.pi * cycles * t)
        return torch.tensor([r0 * (1 + s), r0 * (1 + s), r0 * (1 - 1.2 * s)])

    def center(t: float) -> Tensor:
        return base + torch.tensor([0.0, 0.0, float(axes(t)[2])])

    def parts(t: float) -> list[Primitive]:
        a = axes(t)
        return [Primitive("ellipsoid", center(t), torch.eye(3), a, tex, oid, material_scale=r0 / a)]

    return SceneObject("blob", oid, "nonrigid", desc, parts=parts, position=center)


@dataclass(frozen=True)
class TurningPath:
    """Continuous piecewise-linear path: ``points[i]`` is the position at ``knots[i]`` (knots include 0 and
    1); the velocity changes abruptly at every interior knot."""

    knots: tuple[float, ...]
    points: tuple[tuple[float, float, float], ...]

    def __call__(self, t: float) -> Tensor:
        t = min(max(float(t), 0.0), 1.0)
        k = (
            max(i for i in range(len(self.knots) - 1) if self.knots[i] <= t)
            if t < 1.0
            else len(self.knots) - 2
        )
        t0, t1 = self.knots[k], self.knots[k + 1]
        p0, p1 = torch.tensor(self.points[k]), torch.tensor(self.points[k + 1])
        return p0 + (t - t0) / (t1 - t0) * (p1 - p0)


def make_turning_path(
    gen: torch.Generator, lo, hi, n_knots: int = 4, min_gap: float = 0.14, max_turn_cos: float = 0.5
) -> TurningPath:
    """Random ``TurningPath`` inside the box ``[lo, hi]`` with ``n_knots`` interior knots, at least
    ``min_gap`` apart; at every interior knot the direction turns by more than ``acos(max_turn_cos)``
    (60 degrees by default), and every leg is at least a quarter of the box diagonal long."""
    lo_t, hi_t = torch.tensor(lo, dtype=torch.float64), torch.tensor(hi, dtype=torch.float64)
    inner = [(i + 1) / (n_knots + 1) for i in range(n_knots)]
    for _ in range(1000):
        cand = sorted(torch.rand(n_knots, generator=gen, dtype=torch.float64).mul(0.8).add(0.1).tolist())
        gaps = [b - a for a, b in zip([0.0, *cand], [*cand, 1.0], strict=True)]
        if min(gaps) >= min_gap:
            inner = cand
            break
    knots = (0.0, *inner, 1.0)
    for _ in range(10000):
        pts = lo_t + torch.rand(len(knots), 3, generator=gen, dtype=torch.float64) * (hi_t - lo_t)
        dirs = pts[1:] - pts[:-1]
        if float(dirs.norm(dim=1).min()) < 0.25 * float((hi_t - lo_t).norm()):
            continue
        unit = dirs / dirs.norm(dim=1, keepdim=True)
        if float((unit[:-1] * unit[1:]).sum(1).max()) < max_turn_cos:
            break
    return TurningPath(
        knots=tuple(float(k) for k in knots), points=tuple(tuple(float(v) for v in p) for p in pts)
    )


def _hopper(
    oid: int, path: TurningPath, half: float, tex: Texture, desc: str, spin: float = 4.0
) -> SceneObject:
    """A box on ``path``, spinning at ``spin`` rad per unit time about z, the direction flipping at every
    knot."""

    def yaw(t: float) -> float:
        a = 0.0
        for k, (k0, k1) in enumerate(zip(path.knots[:-1], path.knots[1:], strict=True)):
            a += (-1.0) ** k * spin * min(max(t - k0, 0.0), k1 - k0)
        return a

    def parts(t: float) -> list[Primitive]:
        return [Primitive("box", path(t), rot_z(yaw(t)) @ rot_x(0.4), torch.full((3,), half), tex, oid)]

    return SceneObject("hopper", oid, "abrupt", desc, parts=parts, position=path)


def _transient(
    oid: int, center: Tensor, radius: float, window: tuple[float, float], tex: Texture, desc: str
) -> SceneObject:
    def visible(t: float) -> bool:
        return window[0] <= t < window[1]

    def parts(t: float) -> list[Primitive]:
        return [Primitive("ellipsoid", center, torch.eye(3), torch.full((3,), radius), tex, oid)]

    return SceneObject(
        "ghost", oid, "transient", desc, parts=parts, position=lambda t: center.clone(), visible=visible
    )


def _lamp(oid: int, center: Tensor, radius: float, tex: Texture, desc: str) -> SceneObject:
    prim = Primitive("ellipsoid", center, rot_x(0.5), torch.full((3,), radius), tex, oid, emissive=True)
    return SceneObject(
        "lamp", oid, "appearance", desc, parts=lambda t: [prim], position=lambda t: center.clone()
    )


# -- named scenes -----------------------------------------------------------------------------------


def _textures(seed: int) -> dict[str, Texture]:
    """Palettes and patterns. The backdrop is low-frequency (few Gaussians fit it) except the poster, the
    detail-rich static region; the moving objects carry coarse two-tone patterns (cells >= ~6 px at the
    quick stand-in resolutions), so that a few hundred Gaussians fit each and their motion shows."""
    s = 1000 * seed
    return {
        "room": Texture(
            "checker",
            ((0.78, 0.74, 0.66), (0.58, 0.61, 0.66)),
            scale=1.0,
            noise_scale=0.5,
            noise_amp=0.12,
            seed=s + 1,
        ),
        "table": Texture(
            "noise",
            ((0.42, 0.26, 0.14), (0.6, 0.43, 0.24), (0.38, 0.22, 0.12)),
            scale=0.8,
            noise_scale=0.5,
            noise_amp=0.1,
            seed=s + 2,
        ),
        "pillar": Texture(
            "checker",
            ((0.2, 0.3, 0.6), (0.82, 0.85, 0.9)),
            scale=0.4,
            noise_scale=0.3,
            noise_amp=0.1,
            seed=s + 3,
        ),
        "poster": Texture(
            "noise",
            ((0.9, 0.85, 0.2), (0.1, 0.45, 0.35), (0.8, 0.2, 0.3)),
            scale=0.12,
            noise_scale=0.05,
            noise_amp=0.2,
            seed=s + 4,
        ),
        "cube": Texture(
            "checker",
            ((0.85, 0.2, 0.12), (0.95, 0.88, 0.78)),
            scale=0.3,
            noise_scale=0.3,
            noise_amp=0.08,
            seed=s + 5,
        ),
        "arm": Texture(
            "stripes",
            ((0.12, 0.45, 0.85), (0.95, 0.92, 0.5)),
            scale=0.5,
            noise_scale=0.3,
            noise_amp=0.08,
            seed=s + 6,
        ),
        "blob": Texture(
            "noise",
            ((0.1, 0.5, 0.15), (0.6, 0.85, 0.3), (0.15, 0.4, 0.12)),
            scale=0.6,
            noise_scale=0.3,
            noise_amp=0.08,
            seed=s + 7,
        ),
        "hopper": Texture(
            "checker",
            ((0.55, 0.15, 0.7), (0.95, 0.72, 0.25)),
            scale=0.17,
            noise_scale=0.3,
            noise_amp=0.08,
            seed=s + 8,
        ),
        "ghost": Texture(
            "noise",
            ((0.95, 0.95, 0.95), (0.35, 0.75, 0.85), (0.25, 0.3, 0.6)),
            scale=0.5,
            noise_scale=0.3,
            noise_amp=0.08,
            seed=s + 9,
        ),
        "lamp": Texture(
            "stripes",
            ((1.0, 0.45, 0.1), (1.0, 0.9, 0.4)),
            scale=0.3,
            noise_scale=0.3,
            noise_amp=0.08,
            seed=s + 10,
            hue_cycles=0.25,
        ),
    }


def _n3v_like(seed: int) -> SceneDescription:
    """A room with a table, seen by a forward-facing rig at y ~ -1 looking along +y.

    The moving objects are 0.4-0.65 m across (15-25 px at the quick 128 x 96), apart from each other in
    the image, carry coarse patterns and move by a fraction of their size (0.1-0.25 m, like the hands and
    tools of the N3V kitchen scenes), so that every motion is one the deformation models can represent
    and learn; the regimes still differ (smooth slide, one-cycle swing, pulsation, sharp turns, a
    transient, a colour change). ``dynamics_findings`` in the README says why (measured).
    """
    gen = torch.Generator().manual_seed(seed)
    tx = _textures(seed)
    path = make_turning_path(gen, lo=(-1.0, 1.75, 1.55), hi=(-0.75, 1.8, 1.75), n_knots=2)
    table_top = 0.7

    def cube_path(t: float) -> tuple[Tensor, float]:
        c = torch.tensor([-1.2 + 0.15 * t, 2.0 - 0.04 * math.sin(math.pi * t), table_top + 0.28])
        return c, 0.2 * t

    objects = [
        _static(
            "room",
            1,
            "room",
            (0.0, 1.0, 1.5),
            (4.0, 3.5, 1.5),
            tx["room"],
            "backdrop: inside of a 8x7x3 m box room, large checker tiles",
        ),
        _static(
            "table",
            2,
            "box",
            (0.0, 2.2, table_top / 2),
            (1.7, 0.7, table_top / 2),
            tx["table"],
            "static table (low-frequency wood noise)",
        ),
        _static(
            "pillar", 3, "box", (-2.3, 3.2, 1.1), (0.35, 0.35, 1.1), tx["pillar"], "static checkered pillar"
        ),
        _static(
            "poster",
            4,
            "box",
            (-0.1, 4.46, 1.9),
            (0.9, 0.04, 0.5),
            tx["poster"],
            "static high-frequency poster on the back wall (detail-rich static ROI)",
        ),
        _smooth_cube(
            5,
            cube_path,
            0.28,
            tx["cube"],
            "rigid cube sliding 0.15 m across the table on a low-curvature arc, slow yaw (0.2 rad)",
        ),
        _arm(
            6,
            torch.tensor([0.9, 1.8, 2.15]),
            (0.5, 0.45),
            0.11,
            cycles=1.0,
            phase=0.3 * seed,
            tex=tx["arm"],
            desc="articulated arm (2 boxes + hand) swinging in the image plane, one cycle (hand +-0.12 m)",
            swing=0.15,
            hand=0.13,
        ),
        _blob(
            7,
            torch.tensor([0.4, 2.0, table_top]),
            0.32,
            cycles=1.0,
            tex=tx["blob"],
            desc="non-rigid ellipsoid squashing/stretching (+-15%/18%) once on the table",
            squash=0.15,
        ),
        _hopper(
            8,
            path,
            0.2,
            tx["hopper"],
            desc=f"cube on a piecewise-linear path (0.1-0.2 m legs) with sharp turns at "
            f"t={path.knots[1]:.3f} and t={path.knots[2]:.3f}, spin (2 rad/unit time) reversing at each",
            spin=2.0,
        ),
        _transient(
            9,
            torch.tensor([-0.3, 2.3, table_top + 0.24]),
            0.24,
            (0.3, 0.7),
            tx["ghost"],
            "sphere present only for t in [0.3, 0.7)",
        ),
        _lamp(
            10,
            torch.tensor([2.05, 2.6, 1.03]),
            0.3,
            tx["lamp"],
            "static emissive sphere whose hue turns a quarter cycle",
        ),
    ]
    bbox = torch.tensor([[-4.0, -2.5, 0.0], [4.0, 4.5, 3.0]])
    return SceneDescription(
        "n3v_like", seed, objects, bbox, target=torch.tensor([0.0, 2.2, 1.0]), closed=True
    )


def _dnerf_like(seed: int) -> SceneDescription:
    """Objects on a pedestal in empty space (transparent background), seen by an orbiting camera; the
    moving objects are 0.3-0.5 m across and move by about half their size over the sequence (more than
    in ``n3v_like``: D-NeRF's motions are large), on continuous paths."""
    gen = torch.Generator().manual_seed(seed + 7919)
    tx = _textures(seed)
    path = make_turning_path(gen, lo=(-0.6, -0.6, 0.35), hi=(-0.3, -0.4, 0.6), n_knots=2)

    def cube_path(t: float) -> tuple[Tensor, float]:
        a = -0.1 + 0.5 * t
        return torch.tensor([0.6 * math.cos(a), 0.6 * math.sin(a), 0.2]), a

    objects = [
        _static(
            "pedestal",
            1,
            "box",
            (0.0, 0.0, -0.08),
            (1.0, 1.0, 0.08),
            tx["room"],
            "static pedestal slab, large checker tiles",
        ),
        _static(
            "post",
            2,
            "box",
            (0.0, 0.0, 0.55),
            (0.06, 0.06, 0.55),
            tx["pillar"],
            "static post holding the arm",
        ),
        _static("pillar", 3, "box", (-0.7, 0.7, 0.35), (0.14, 0.14, 0.35), tx["poster"], "static pillar"),
        _smooth_cube(4, cube_path, 0.2, tx["cube"], "rigid cube on a circular arc (0.5 rad) around the post"),
        _arm(
            5,
            torch.tensor([0.0, 0.0, 1.1]),
            (0.4, 0.35),
            0.08,
            cycles=1.0,
            phase=0.3 * seed,
            tex=tx["arm"],
            desc="articulated arm hanging from the post, one swing cycle",
            swing=0.3,
            hand=0.1,
        ),
        _blob(
            6,
            torch.tensor([0.45, -0.5, 0.0]),
            0.22,
            cycles=1.0,
            tex=tx["blob"],
            desc="non-rigid ellipsoid squashing/stretching (+-20%/24%) once",
            squash=0.2,
        ),
        _hopper(
            7,
            path,
            0.14,
            tx["hopper"],
            desc=f"cube on a piecewise-linear path with sharp turns at t={path.knots[1]:.3f} and "
            f"t={path.knots[2]:.3f}, spin (3 rad/unit time) reversing at each",
            spin=3.0,
        ),
        _transient(
            8,
            torch.tensor([-0.3, 0.45, 0.22]),
            0.2,
            (0.3, 0.7),
            tx["ghost"],
            "sphere present only for t in [0.3, 0.7)",
        ),
        _lamp(
            9,
            torch.tensor([0.6, 0.45, 0.25]),
            0.2,
            tx["lamp"],
            "emissive striped sphere whose hue turns a quarter cycle",
        ),
    ]
    bbox = torch.tensor([[-1.0, -1.0, -0.16], [1.0, 1.0, 1.2]])
    return SceneDescription(
        "dnerf_like", seed, objects, bbox, target=torch.tensor([0.0, 0.0, 0.4]), closed=False
    )


SCENES: dict[str, Callable[[int], SceneDescription]] = {"n3v_like": _n3v_like, "dnerf_like": _dnerf_like}


def build_scene(name: str, seed: int = 0) -> SceneDescription:
    """The named procedural scene (deterministic in ``seed``)."""
    if name not in SCENES:
        raise KeyError(f"unknown synthetic scene {name!r}; valid: {sorted(SCENES)}")
    return SCENES[name](int(seed))
