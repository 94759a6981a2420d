"""Robogym-rearrange (Appendix C): k objects of 94 shapes and 13 colours on a 0.6 x 0.8 table.

Adapted from the rearrange task of OpenAI's robogym (its robot replaced by a pick-and-move
primitive, as in the paper): objects differ in shape, size and orientation, positions are
continuous, and the bird's-eye camera's perspective makes an object look a little different
in different places. MuJoCo (official bindings) simulates and renders it headless.

Arena coordinates are metres, origin at the table's centre, z up, the table top at z = 0;
+x is to the right of the image, +y towards its top. Each object is scaled so that its
longest dimension is `object_size` (tall thin objects look smaller from above), turned by a
random yaw at reset that it keeps for the episode (orientation is unchanged by moves and
goals), and sits on the table.

Action `(w, dw)`: a Box of 6 floats `(wx, wy, wz, dwx, dwy, dwz)`; z is ignored. In order:
  1. pick: the object whose centre is nearest to `w` (x, y) and within `pick_threshold`;
     none -> no-op.
  2. place at `w + dw`: a target where the object would hang over the table's edge or
     overlap another object -> no-op. Otherwise the object is put there at rest on the
     table, with its orientation.
Placement is kinematic: MuJoCo computes the poses the camera draws but steps no physics, so
an object keeps its orientation and place until it is moved (Appendix C); with a physics
settle, untouched objects tipped and crept until footprints overlapped (docs/HISTORY.md,
"robogym-rearrange: kinematic placement"). tests/envs/test_robogym_rearrange.py checks the simulator's
poses against the ones set.

Tasks never fail to sample: footprints are drawn at random, largest first, and after 20 dead
ends on a fixed lattice that holds the largest footprint in each cell (`lattice`); an object
count whose starts and goals the lattice cannot hold is refused when the env is made.
A constraint holds when its object is within `success_threshold` (x, y) of its goal.

Each object is one geom whose shape `_show` sets from a table of compiled shapes
(`_shape_table`), and `TopCamera` renders the image and the masks with MuJoCo's low-level API,
both for speed (docs/benchmarks.md, `bench envs`); tests/envs/test_robogym_rearrange.py pins a digest of what
the env returns.

Rendering: MuJoCo reads `MUJOCO_GL` when it is first imported. If it is unset, importing
ncs_lite picks EGL, then OSMesa, whichever library the system has (`headless.py`); with
neither, making the env fails with a message naming both (see `_renderer`).
"""
from __future__ import annotations

import functools
import os
from dataclasses import asdict, dataclass

import numpy as np
from gymnasium import spaces

import mujoco  # after ncs_lite/__init__.py chose MUJOCO_GL (envs/headless.py)

from .common import RearrangeEnv, check_index, check_number, check_task, constrained_count, horizon
from .headless import render_failure_advice
from .objects import COLOURS, OBJECTS, load_mesh

# The floor beyond the table has the table's colour and the light is directional (no
# gradient): the `reduced` recipe separates objects from a uniform background, as
# block-rearrange's; on a darker floor under a spot light it gave one slot to the table and
# shared the rest evenly (docs/HISTORY.md, "robogym-rearrange before kinematic placement").
TABLE_RGB = (0.55, 0.50, 0.45)
FLOOR_RGB = TABLE_RGB
ONE_HOT_SHAPES = np.eye(len(OBJECTS), dtype=np.float32)   # the shape half of info["types"]
BACKDROP_GROUP = 1        # the floor: in the RGB pass, not in the segmentation pass
HIDDEN_GROUP = 5          # unconstrained objects in the goal image
# what makes a geom one shape or another; `_show` copies them from `_shape_table`
SHAPE_FIELDS = ("type", "dataid", "size", "rbound", "aabb", "pos", "quat", "sameframe")


@dataclass(frozen=True)
class RobogymRearrangeConfig:
    """Everything that defines a robogym-rearrange task distribution (stored with data)."""

    num_objects: int = 4
    goal: str = "complete"            # "complete": every object moves; "partial": a subset
    num_constrained: int | None = None
    horizon_multiplier: float = 4.0   # horizon = ceil(multiplier x minimum steps)
    action_noise: float = 0.0         # std (m) of Gaussian noise added to (w, dw) each step
    table_x: float = 0.6              # table size (m), Appendix C
    table_y: float = 0.8
    object_size: float = 0.11         # every object's longest dimension (m)
    gap: float = 0.005                # min clearance (m) between sampled footprints
    pick_threshold: float = 0.05      # Appendix C: match threshold of the pick
    success_threshold: float = 0.05   # ... and of the goal placement
    camera_tilt: float = 15.0         # degrees from straight down: visible perspective
    image_size: int = 64

    def __post_init__(self):
        check_task(self, max_objects=len(COLOURS))
        for name in ("table_x", "table_y", "object_size", "pick_threshold", "success_threshold"):
            check_number(self, name)
        check_number(self, "gap", allow_zero=True)
        check_number(self, "camera_tilt", allow_zero=True)
        if self.camera_tilt >= 60:
            raise ValueError(f"camera_tilt must be < 60 degrees (a bird's-eye view), got {self.camera_tilt}")
        if self.object_size > min(self.table_x, self.table_y) / 2:
            raise ValueError(f"object_size {self.object_size} m does not fit a "
                             f"{self.table_x} x {self.table_y} m table twice over")

    @property
    def constrained(self) -> int:
        return constrained_count(self)


def object_geometry(entry, size: float, asset_name: str = "mesh") -> dict:
    """One object, scaled so its longest dimension is `size`: its MJCF geom attributes (an
    optional mesh asset), its resting height (centre above the table) and footprint radius
    (a circle around the centre that holds it at any yaw)."""
    name, kind, spec = entry
    if kind == "mesh":
        v, f = load_mesh(spec[0], tuple(spec[1]), spec[2])
        lo, hi = v.min(0), v.max(0)
        v = (v - (lo + hi) / 2) * (size / float((hi - lo).max()))     # centred, longest side = size
        asset = f'<mesh name="{asset_name}" inertia="convex" vertex="{_fmt(v)}" face="{" ".join(map(str, f.ravel()))}"/>'
        return {"geom": f'type="mesh" mesh="{asset_name}"', "asset": asset, "rest": float(-v[:, 2].min()),
                "radius": float(np.linalg.norm(v[:, :2], axis=1).max())}
    p = np.asarray([x for x in spec if not isinstance(x, str)], float)
    lying = "lying" in spec
    if kind == "box":
        half = p / p.max() * size / 2
        return {"geom": f'type="box" size="{_fmt(half)}"', "rest": half[2], "radius": float(np.hypot(*half[:2]))}
    if kind == "sphere":
        return {"geom": f'type="sphere" size="{size / 2}"', "rest": size / 2, "radius": size / 2}
    if kind == "ellipsoid":
        radii = p / p.max() * size / 2
        return {"geom": f'type="ellipsoid" size="{_fmt(radii)}"', "rest": radii[2], "radius": float(radii[:2].max())}
    # cylinder (diameter, length) and capsule (diameter, length of its straight part)
    d, length = p
    total = length + d if kind == "capsule" else length
    s = size / max(d, total)
    r, half_len, half_total = d * s / 2, length * s / 2, total * s / 2
    turn = ' quat="0.70710678 0 0.70710678 0"' if lying else ""    # axis along x
    return {"geom": f'type="{kind}" size="{r} {half_len}"{turn}',
            "rest": r if lying else half_total,
            "radius": float(np.hypot(half_total, r)) if lying else r}


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.ravel(v))


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


class RobogymRearrange(RearrangeEnv):
    """Goal-conditioned rearrangement of varied objects with image observations.

    Observation: {"image": (64, 64, 3) uint8, "goal": (64, 64, 3) uint8}.
    info (ground truth for metrics and the oracle only; no learned agent may read it): the
    block-rearrange contract (positions (k, 3), colors (k, 3), goal_positions (k, 3),
    constrained, masks, goal_masks, satisfied, moved, picked, min_steps, horizon, steps,
    is_success) plus shapes (k,) indices into `objects.OBJECTS` and types (k, 3 + 94): the
    colour and a one-hot shape, what an object is.
    """

    def __init__(self, num_objects: int = 4, goal: str = "complete", num_constrained=None,
                 horizon_multiplier: float = 4.0, action_noise: float = 0.0,
                 render_mode: str | None = None, **kwargs):
        self._renderer = None
        self.config = cfg = RobogymRearrangeConfig(
            num_objects=num_objects, goal=goal, num_constrained=num_constrained,
            horizon_multiplier=horizon_multiplier, action_noise=action_noise, **kwargs)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        hx, hy = cfg.table_x / 2, cfg.table_y / 2
        self.action_space = spaces.Box(
            low=np.array([-hx, -hy, 0.0, -2 * hx, -2 * hy, -0.1], np.float32),
            high=np.array([hx, hy, 0.1, 2 * hx, 2 * hy, 0.1], np.float32), dtype=np.float32)
        img = spaces.Box(0, 255, (cfg.image_size, cfg.image_size, 3), np.uint8)
        self.observation_space = spaces.Dict({"image": img, "goal": img})

        self._geometry, self._shape_fields = _shape_table(cfg.object_size)
        self._rest = np.array([g["rest"] for g in self._geometry])
        self._radius = np.array([g["radius"] for g in self._geometry])
        k = cfg.num_objects
        self._lattice = lattice(cfg, float(self._radius.max()))
        if k + cfg.constrained > len(self._lattice):
            raise ValueError(f"num_objects={k} with {cfg.goal} goals needs {k + cfg.constrained} footprints "
                             f"(starts and goals), but the {cfg.table_x} x {cfg.table_y} m table holds "
                             f"{len(self._lattice)} for certain; use fewer objects, a partial goal or a smaller object_size")
        self.model = mujoco.MjModel.from_xml_string(_mjcf(cfg, self._geometry, k))
        self.data = mujoco.MjData(self.model)
        self._geom = np.array([self.model.geom(f"o{i}").id for i in range(k)])   # object i's one geom
        # collision filtering starts at the body level, fixed at compile from the geoms (hidden
        # then): objects must collide whatever shape they show
        bodies = self.model.geom_bodyid[self._geom]
        self.model.body_contype[bodies] = 1
        self.model.body_conaffinity[bodies] = 1
        self.model.stat.extent = _extent_over_shapes(self.model, self._geom, self._shape_fields)
        self._renderer = _renderer(self.model, cfg.image_size)
        self._shapes = np.zeros(k, np.int64)
        self._colors = COLOURS[:k].copy()
        self._yaw = np.zeros(k)
        self._goal = np.zeros((k, 2))
        self._constrained = np.zeros(k, bool)
        self._image = self._goal_image = None
        self._steps = 0

    # ----------------------------------------------------------------- scene
    def _show(self, visible: np.ndarray) -> None:
        """Make object i's geom its shape, drawn (visible[i]) or not; only drawn objects collide."""
        m, g = self.model, self._geom
        for name in SHAPE_FIELDS:
            getattr(m, f"geom_{name}")[g] = self._shape_fields[name][self._shapes]
        m.geom_rgba[g, :3] = self._colors
        m.geom_rgba[g, 3] = 1.0
        m.geom_group[g] = np.where(visible, 0, HIDDEN_GROUP)
        m.geom_contype[g] = m.geom_conaffinity[g] = visible.astype(m.geom_contype.dtype)

    def _set_pose(self, i: int, xy) -> None:
        q = self.data.qpos[7 * i: 7 * i + 7]
        q[:2], q[2], q[3:] = xy, self._rest[self._shapes[i]], _yaw_quat(self._yaw[i])
        self.data.qvel[6 * i: 6 * i + 6] = 0.0

    def _update_kinematics(self) -> None:
        """The poses the camera draws, from the ones set: no physics step (module docstring)."""
        self.data.qvel[:] = 0.0
        mujoco.mj_kinematics(self.model, self.data)

    def _render(self):
        """(H, W, 3) uint8 image, (k, H, W) bool masks of the objects."""
        return self._renderer.render(self.data, self._geom)

    def positions(self) -> np.ndarray:
        """(k, 3) object centres (x, y, z) in metres."""
        return self.data.qpos.reshape(-1, 7)[:, :3].astype(np.float32).copy()

    # ------------------------------------------------------------------- API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._check_open("reset")
        super().reset(seed=seed)
        cfg, rng = self.config, self.np_random
        k, m = cfg.num_objects, cfg.constrained
        self._shapes = rng.choice(len(OBJECTS), size=k, replace=False)
        self._colors = COLOURS[rng.choice(len(COLOURS), size=k, replace=False)].copy()
        self._yaw = rng.uniform(-np.pi, np.pi, size=k)
        self._constrained = np.zeros(k, bool)
        self._constrained[rng.choice(k, size=m, replace=False)] = True
        # starts for all k objects, then goals for the constrained ones, no footprints overlapping
        radii = self._radius[self._shapes]
        spots = self._sample_spots(np.concatenate([radii, radii[self._constrained]]), rng)
        start = spots[:k]
        self._goal = start.copy()
        self._goal[self._constrained] = spots[k:]
        self.min_steps = int(m)
        self.horizon = horizon(cfg, self.min_steps)
        self._steps = 0
        # the goal image: only the constrained objects, at their goals
        self._show(self._constrained)
        for i in range(k):
            self._set_pose(i, self._goal[i])
        mujoco.mj_forward(self.model, self.data)
        self._goal_image, self._goal_masks = self._render()
        self._show(np.ones(k, bool))
        for i in range(k):
            self._set_pose(i, start[i])
        self._update_kinematics()
        return self._observe(moved=-1)

    def _closed(self) -> bool:
        return getattr(self, "_renderer", None) is None

    def _after_move(self) -> None:
        self._update_kinematics()

    def close(self):
        if getattr(self, "_renderer", None) is not None:
            self._renderer.close()
            self._renderer = None

    # --------------------------------------------------------------- helpers
    def _sample_spots(self, radii: np.ndarray, rng) -> np.ndarray:
        """Centres (n, 2) on the table for footprints of `radii`, pairwise clear by `gap`:
        largest first, each uniform over where it fits (`_free_spot`); a dead end starts over,
        and after 20 of them each footprint takes a random cell of `self._lattice`, which holds
        the largest footprint in each cell (the constructor checked there are enough)."""
        order = np.argsort(-radii, kind="stable")
        for _ in range(20):
            spots = np.zeros((len(radii), 2))
            for n, i in enumerate(order):
                p = self._free_spot(radii[i], spots[order[:n]], radii[order[:n]] + self.config.gap, rng)
                if p is None:
                    break
                spots[i] = p
            else:
                return spots
        # a cell's centre may move by up to r_max - r in any direction: two neighbours then stay
        # pitch - (r_max - r_i) - (r_max - r_j) = r_i + r_j + gap apart, and r inside the table
        cells = self._lattice[rng.choice(len(self._lattice), size=len(radii), replace=False)]
        slack = self._radius.max() - radii
        angle, reach = rng.uniform(0, 2 * np.pi, len(radii)), np.sqrt(rng.uniform(0, 1, len(radii))) * slack
        return cells + np.stack([np.cos(angle), np.sin(angle)], 1) * reach[:, None]

    def _free_spot(self, r: float, centres: np.ndarray, radii: np.ndarray, rng, pitch: float = 0.01):
        """A centre drawn uniformly (to `pitch`) among those where a footprint of radius r lies on
        the table and clear of `centres` by r + radii; None when there is none. A random offset
        of the candidate lattice keeps the draw continuous."""
        cfg = self.config
        lo = np.array([-cfg.table_x / 2 + r, -cfg.table_y / 2 + r])
        if np.any(lo > 0):
            return None
        offset = rng.uniform(0, pitch, 2)
        xs, ys = (np.arange(lo[i] + offset[i], -lo[i] + 1e-12, pitch) for i in range(2))
        free = np.ones((len(xs), len(ys)), bool)     # the lattice, x-major
        for c, rc in zip(np.asarray(centres).reshape(-1, 2), np.asarray(radii).reshape(-1)):
            free &= (xs[:, None] - c[0]) ** 2 + (ys[None, :] - c[1]) ** 2 >= (r + rc) ** 2
        cand = np.flatnonzero(free)
        if not len(cand):
            return None
        i, j = divmod(int(cand[rng.integers(len(cand))]), len(ys))
        return np.array([xs[i], ys[j]])

    def fits(self, obj: int, xy) -> bool:
        """Whether object `obj` can be put down at xy: on the table, clear of every other."""
        cfg = self.config
        r = self._radius[self._shapes[obj]]
        xy = np.asarray(xy, float)
        if abs(xy[0]) > cfg.table_x / 2 - r or abs(xy[1]) > cfg.table_y / 2 - r:
            return False
        centres, radii = self.positions()[:, :2], self._radius[self._shapes]
        others = np.arange(len(centres)) != obj
        return bool(np.all(np.linalg.norm(centres[others] - xy, axis=1) >= radii[others] + r))

    def _apply(self, action: np.ndarray) -> int:
        """Pick and move; return (the picked object or -1, the moved object or -1 for a no-op)."""
        w, target = action[:2], action[:2] + action[3:5]
        dist = np.linalg.norm(self.positions()[:, :2] - w, axis=1)
        picked = int(np.argmin(dist))
        if dist[picked] > self.config.pick_threshold:
            return -1, -1
        if not self.fits(picked, target):
            return picked, -1
        self._set_pose(picked, target)
        return picked, picked

    def _observe(self, moved: int, picked: int = -1):
        self._image, masks = self._render()
        cfg = self.config
        pos = self.positions()
        goal = np.concatenate([self._goal, self._rest[self._shapes][:, None]], 1).astype(np.float32)
        satisfied = np.linalg.norm(pos[:, :2] - goal[:, :2], axis=1) <= cfg.success_threshold
        types = np.concatenate([self._colors, ONE_HOT_SHAPES[self._shapes]], 1)
        info = {
            "positions": pos, "goal_positions": goal, "colors": self._colors.copy(),
            "shapes": self._shapes.copy(), "types": types,
            "constrained": self._constrained.copy(), "masks": masks,
            "goal_masks": self._goal_masks.copy(), "satisfied": satisfied, "moved": int(moved), "picked": int(picked),
            "min_steps": self.min_steps, "horizon": self.horizon, "steps": self._steps,
            "is_success": bool(np.all(satisfied[self._constrained])),
        }
        return {"image": self._image.copy(), "goal": self._goal_image.copy()}, info

    # ------------------------------------------------------- for data + tests
    def pick_and_move(self, obj: int, xy) -> np.ndarray:
        """The action that moves object `obj` to table position xy (no noise): (w, dw)."""
        obj = check_index("obj", obj, self.config.num_objects)
        w = self.positions()[obj]
        dw = np.asarray(xy, np.float32) - w[:2]
        wz = np.clip(w[2], 0.0, float(self.action_space.high[2]))
        return np.array([w[0], w[1], wz, dw[0], dw[1], 0.0], np.float32)

    def random_pick_and_move(self, rng: np.random.Generator) -> np.ndarray:
        """A 'video demonstration' action: a random object to a random place where it fits
        (uniform over such places; back where it is if there is none)."""
        obj = int(rng.integers(self.config.num_objects))
        others = np.arange(self.config.num_objects) != obj
        pos = self.positions()[:, :2]
        xy = self._free_spot(self._radius[self._shapes[obj]], pos[others], self._radius[self._shapes[others]], rng)
        return self.pick_and_move(obj, pos[obj] if xy is None else xy)

    def describe(self) -> dict:
        return {"env": "robogym-rearrange", **asdict(self.config)}


def lattice(cfg: RobogymRearrangeConfig, r_max: float) -> np.ndarray:
    """(n, 2) centres of a square lattice on the table, pitch 2 r_max + gap, each at least r_max
    from the edge: any footprints of radius <= r_max, one per cell, fit and keep clear by `gap`.
    Its size is how many footprints a task can always hold."""
    pitch = 2 * r_max + cfg.gap
    axes = []
    for side in (cfg.table_x, cfg.table_y):
        span = side - 2 * r_max
        n = int(np.floor(span / pitch + 1e-9)) + 1 if span >= 0 else 0
        axes.append((np.arange(n) - (n - 1) / 2) * pitch)
    xs, ys = np.meshgrid(*axes, indexing="ij")
    return np.stack([xs.ravel(), ys.ravel()], 1)


def _shape_table_mjcf(geometry) -> str:
    bodies = "".join(_object_body(j, g) for j, g in enumerate(geometry))
    return f'<mujoco><compiler inertiafromgeom="false"/><asset>{_assets(geometry)}</asset><worldbody>{bodies}</worldbody></mujoco>'


@functools.lru_cache(maxsize=4)
def _shape_table(object_size: float):
    """Each shape's geometry (`object_geometry`) and its compiled geom fields (SHAPE_FIELDS),
    read from a model with one body per shape. An env's objects have one geom each, which
    `_show` turns into any shape: hidden geoms, one per shape in every object, would make every
    physics step dearer (MuJoCo's kinematics and collision loops visit every geom)."""
    geometry = [object_geometry(e, object_size, f"shape{j}") for j, e in enumerate(OBJECTS)]
    m = mujoco.MjModel.from_xml_string(_shape_table_mjcf(geometry))
    ids = [m.geom(f"o{j}").id for j in range(len(OBJECTS))]
    return geometry, {name: getattr(m, f"geom_{name}")[ids].copy() for name in SHAPE_FIELDS}


def _extent_over_shapes(model, geoms: np.ndarray, fields: dict) -> float:
    """MuJoCo's automatic `stat.extent` (the longest side of the box around every body and every
    geom's bounding sphere but planes, at qpos0) with each object any of the shapes. The camera's
    clip planes scale with it, so it must not depend on the shape an object was compiled with;
    this is also the extent of a model that holds every shape in every object (the first version)."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    points = [data.xpos[1:]]
    for g in range(model.ngeom):
        if g in geoms:       # the object's body, with every shape's offset and radius
            centres = data.xpos[model.geom_bodyid[g]] + fields["pos"]
            points += [centres - fields["rbound"][:, None], centres + fields["rbound"][:, None]]
        elif model.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE:
            points += [data.geom_xpos[g] - model.geom_rbound[g], data.geom_xpos[g] + model.geom_rbound[g]]
    points = np.concatenate([np.reshape(p, (-1, 3)) for p in points])
    return float((points.max(0) - points.min(0)).max())


def _assets(geometry) -> str:
    # every shape's mesh, in one order, so a geom's mesh id means the same shape in each model
    return "".join(g.get("asset", "") for g in geometry)


def _object_body(i: int, g: dict) -> str:
    # hidden at compile (no contact, no drawing): `_show` decides
    return (f'<body name="o{i}" pos="{i} 5 1"><freejoint/>'
            f'<inertial pos="0 0 0" mass="0.1" diaginertia="1e-4 1e-4 1e-4"/>'
            f'<geom name="o{i}" {g["geom"]} group="{HIDDEN_GROUP}" contype="0" conaffinity="0"/></body>')


def _mjcf(cfg: RobogymRearrangeConfig, geometry, k: int) -> str:
    hx, hy = cfg.table_x / 2, cfg.table_y / 2
    t = np.radians(cfg.camera_tilt)
    height = 1.0
    # the view spans the table's long side plus a margin, seen from `height` at `tilt`
    fovy = 2 * np.degrees(np.arctan((hy + 0.02) * np.cos(t) / height))
    cam_pos = (0.0, -height * np.tan(t), height)
    size = cfg.image_size
    return f"""<mujoco model="robogym-rearrange">
  <compiler inertiafromgeom="false"/>
  <option timestep="0.002"/>
  <visual><quality shadowsize="0" offsamples="0"/><global offwidth="{size}" offheight="{size}"/>
    <headlight ambient="0.55 0.55 0.55" diffuse="0 0 0" specular="0 0 0"/></visual>
  <asset>{_assets(geometry)}</asset>
  <worldbody>
    <light directional="true" pos="0 0 2" dir="-0.3 0.3 -1" diffuse="0.45 0.45 0.45" specular="0 0 0" castshadow="false"/>
    <geom name="floor" type="plane" size="3 3 0.1" pos="0 0 -0.4" rgba="{_fmt(FLOOR_RGB)} 1" contype="0" conaffinity="0" group="{BACKDROP_GROUP}"/>
    <geom name="table" type="box" size="{hx} {hy} 0.02" pos="0 0 -0.02" rgba="{_fmt(TABLE_RGB)} 1"/>
    <camera name="top" pos="{_fmt(cam_pos)}" xyaxes="1 0 0 0 {np.cos(t):.6f} {np.sin(t):.6f}" fovy="{fovy:.4f}"/>
    {''.join(_object_body(i, geometry[0]) for i in range(k))}
  </worldbody>
</mujoco>"""


class TopCamera:
    """The image and the objects' masks from the fixed camera: an RGB pass, then a segmentation
    pass of the objects and the table (which hides any part of an object that reaches
    below its top), each read back at once. MuJoCo's low-level API, as `mujoco.Renderer` uses
    it (GL context, `MjrContext`, offscreen buffer), without its per-call allocations and its
    second scene update. Both passes draw at the buffer's origin: drawn beside each other (one
    read instead of two) a few pixels where an object meets the table come out differently
    from the separate passes the shipped data were made with."""

    def __init__(self, model, size: int):
        if model.ngeom >= 255:
            raise ValueError(f"TopCamera reads a segment id from one byte: {model.ngeom} geoms are too many")
        self.model, self.size = model, size
        self._gl = mujoco.GLContext(size, size)
        self._gl.make_current()
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = model.camera("top").id
        self._options = mujoco.MjvOption(), mujoco.MjvOption()   # RGB; segmentation
        for option in self._options:
            option.geomgroup[HIDDEN_GROUP] = 0
        self._options[1].geomgroup[BACKDROP_GROUP] = 0
        self._scenes = mujoco.MjvScene(model, maxgeom=model.ngeom), mujoco.MjvScene(model, maxgeom=model.ngeom)
        self._scenes[1].flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        self._scenes[1].flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1
        self._rect = mujoco.MjrRect(0, 0, size, size)
        self._pixels = np.empty((2, size, size, 3), np.uint8)

    def render(self, data, geoms: np.ndarray):
        """(H, W, 3) uint8 image and (len(geoms), H, W) bool masks of those geoms."""
        if self._context is None:
            raise ValueError("render() on a closed env; make a new one")
        self._gl.make_current()
        for option, scene, pixels in zip(self._options, self._scenes, self._pixels):
            mujoco.mjv_updateScene(self.model, data, option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
            mujoco.mjr_render(self._rect, scene, self._context)
            mujoco.mjr_readPixels(pixels, None, self._rect, self._context)
        rgb, seg = self._pixels[:, ::-1]                 # OpenGL's rows run bottom up
        # a pixel's id colour is 1 + its geom's segid (its index in the scene), red byte lowest;
        # the scene holds under 256 geoms, so red alone names it
        scene = self._scenes[1]
        ids = np.full(len(geoms), -1, np.int16)
        for g in scene.geoms[:scene.ngeom]:
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and g.segid >= 0:
                ids[geoms == g.objid] = g.segid + 1
        return rgb.copy(), seg[..., 0].astype(np.int16)[None] == ids[:, None, None]

    def close(self) -> None:
        if self._context is not None:
            self._gl.make_current()
            self._context.free()
            self._context = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None


def _renderer(model, size: int) -> TopCamera:
    """A headless camera, or a RuntimeError that says what to install or set."""
    try:
        return TopCamera(model, size)
    except Exception as e:  # noqa: BLE001 - GL setup fails in many library-specific ways
        raise RuntimeError(
            f"robogym-rearrange could not render headless with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} "
            f"({type(e).__name__}: {e}). {render_failure_advice()}") from e
