"""The 94 objects and 13 colours of robogym-rearrange (Appendix C), with source and licence.

The paper draws its objects from the YCB set plus basic shapes. YCB cannot be installed
from a package registry, so the kit's 94 are:

  16 MuJoCo primitives (boxes, spheres, ellipsoids, cylinders, capsules in several
     proportions), drawn by MuJoCo itself: no file, no licence needed;
   9 named meshes shipped in `pybullet_data` (bunny, duck, teddy, soccer ball, stone, mug,
     lego brick, jenga block, domino);
  69 of the 1000 procedurally generated objects in `pybullet_data/random_urdfs`: those
     whose outline seen from above covers the most of the square of their longest
     dimension (>= 78 %; `chunkiness`), since at 64 x 64 pixels a thin one would be a few
     pixels or none (the rule is checked in tests/envs/test_robogym_rearrange.py).

`pybullet_data` is part of the `pybullet` wheel on PyPI (bullet3, zlib licence; the domino's
own notice asks for a citation of PyBullet, given in the README's "Citation and licences").
Every object is later scaled so that its longest dimension is the env's `object_size`
(Appendix C), so only the proportions given here matter.

An entry: (name, kind, spec), kind "box" | "sphere" | "ellipsoid" | "cylinder" | "capsule"
with spec the MuJoCo size proportions (and "lying" for a cylinder or capsule on its side),
or kind "mesh" with spec (path inside pybullet_data, per-axis prescale, quarter turns about x
that bring its top up).
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pybullet_data

SOURCE_PRIMITIVE = "MuJoCo primitive (no file)"
SOURCE_PYBULLET = "pybullet_data, from the pybullet wheel on PyPI (bullet3, zlib licence)"

PRIMITIVES = (
    ("cube", "box", (1.0, 1.0, 1.0)),
    ("tile", "box", (1.0, 1.0, 0.3)),
    ("brick", "box", (1.0, 0.5, 0.5)),
    ("bar", "box", (1.0, 0.3, 0.3)),
    ("plank", "box", (1.0, 0.6, 0.2)),
    ("pillar", "box", (0.4, 0.4, 1.0)),
    ("ball", "sphere", (1.0,)),
    ("egg", "ellipsoid", (1.0, 0.65, 0.65)),
    ("lens", "ellipsoid", (1.0, 1.0, 0.4)),
    ("dome", "ellipsoid", (0.6, 0.6, 1.0)),
    ("puck", "cylinder", (1.0, 0.3)),
    ("can", "cylinder", (0.5, 1.0)),
    ("log", "cylinder", (0.35, 1.0, "lying")),
    ("pill", "capsule", (0.5, 0.5)),
    ("bean", "capsule", (0.4, 0.6, "lying")),
    ("disk", "cylinder", (1.0, 0.12)),
)

NAMED_MESHES = (
    ("bunny", "mesh", ("bunny.obj", (1, 1, 1), 0)),
    ("duck", "mesh", ("duck.obj", (1, 1, 1), 1)),
    ("teddy", "mesh", ("teddy2_VHACD_CHs.obj", (1, 1, 1), 0)),
    ("soccer ball", "mesh", ("soccerball.obj", (1, 1, 1), 0)),
    ("stone", "mesh", ("stone.obj", (1, 1, 1), 0)),
    ("mug", "mesh", ("objects/mug.obj", (1, 1, 1), 0)),
    ("lego", "mesh", ("lego/lego.obj", (1, 1, 1), 1)),
    ("jenga block", "mesh", ("jenga/jenga.obj", (0.15, 0.05, 0.03), 0)),
    ("domino", "mesh", ("domino/domino.obj", (1, 1, 1), 1)),
)

RANDOM_CHOSEN = (13, 17, 32, 38, 40, 44, 66, 123, 125, 131, 137, 149, 159, 175, 200, 201, 254, 264,
                 265, 279, 295, 308, 332, 335, 344, 349, 367, 430, 432, 442, 472, 478, 480, 495, 498,
                 500, 521, 529, 530, 571, 608, 616, 634, 652, 663, 704, 709, 717, 721, 735, 739, 757,
                 764, 770, 775, 792, 793, 795, 808, 864, 877, 878, 885, 893, 935, 945, 951, 956, 976)
RANDOM_MESHES = tuple((f"random {i:03d}", "mesh", (f"random_urdfs/{i:03d}/{i:03d}.obj", (1, 1, 1), 0))
                      for i in RANDOM_CHOSEN)

OBJECTS = PRIMITIVES + NAMED_MESHES + RANDOM_MESHES
assert len(OBJECTS) == 94

# 13 colours far apart in hue and lightness (Appendix C: "a set of 13").
COLOURS = np.array([
    [0.90, 0.10, 0.10], [0.10, 0.70, 0.15], [0.15, 0.30, 0.95], [0.95, 0.85, 0.10],
    [0.85, 0.15, 0.85], [0.10, 0.85, 0.90], [0.98, 0.55, 0.05], [0.97, 0.97, 0.97],
    [0.10, 0.10, 0.10], [0.55, 0.30, 0.10], [0.50, 0.10, 0.60], [0.55, 0.95, 0.45],
    [0.98, 0.65, 0.75],
], dtype=np.float32)
COLOUR_NAMES = ("red", "green", "blue", "yellow", "magenta", "cyan", "orange", "white",
                "black", "brown", "purple", "lime", "pink")


def source(entry) -> str:
    """Where an object comes from (for notebook 01's table of sources)."""
    name, kind, spec = entry
    return SOURCE_PRIMITIVE if kind != "mesh" else f"{SOURCE_PYBULLET}: {spec[0]}"


def pybullet_data_dir() -> Path:
    return Path(pybullet_data.getDataPath())


@lru_cache(maxsize=None)
def load_mesh(path: str, prescale: tuple, quarter_turns: int) -> tuple[np.ndarray, np.ndarray]:
    """An OBJ file inside pybullet_data as (vertices (n, 3) prescaled and turned about x,
    triangles (m, 3) 0-based), all its objects ("o" groups) merged: MuJoCo's own OBJ reader
    keeps the faces of the first object only, which drops most of a random_urdfs object."""
    full = pybullet_data_dir() / path
    if not full.is_file():
        raise FileNotFoundError(f"robogym-rearrange's mesh {path!r} is missing from {full.parent}; "
                                "reinstall pybullet (`pip install -r environment.txt`)")
    verts, faces = [], []
    for line in full.read_text(errors="replace").splitlines():
        if line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            # "f 1 2 3", "f 1/1 2/2 3/3", "f 1//1 ..." or negative (relative) indices; fan polygons
            idx = [int(t.split("/")[0]) for t in line.split()[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            faces += [[idx[0], idx[a], idx[a + 1]] for a in range(1, len(idx) - 1)]
    v = np.asarray(verts, np.float64) * np.asarray(prescale, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(v) < 4 or not np.isfinite(v).all() or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"mesh {full} has {len(v)} vertices (finite: {np.isfinite(v).all()}) and "
                         f"{len(f)} valid-looking faces: not a usable object")
    return v @ quarter_turn_matrix(quarter_turns).T, f


def chunkiness(v: np.ndarray) -> float:
    """Area of the outline seen from above (convex hull of x, y) / (longest dimension)^2."""
    from scipy.spatial import ConvexHull  # local: half a second to import, for this check of the object set alone

    return float(ConvexHull(v[:, :2]).volume / (v.max(0) - v.min(0)).max() ** 2)


def quarter_turn_matrix(quarter_turns: int) -> np.ndarray:
    """Rotation by quarter_turns x 90 degrees about the x axis."""
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][quarter_turns % 4]
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], np.float64)
