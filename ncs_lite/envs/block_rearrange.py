"""Block-rearrange (Appendix C): k cubes on a 4x4 grid, moved by pick-and-move actions.

The scene is rendered by PyBullet's TinyRenderer in DIRECT mode (headless, CPU). Objects
never need physics: a pick-and-move teleports the picked cube to the grid cell nearest to
`w + dw`, so a step costs one render. Arena coordinates are metres, origin at the grid
centre, z up; the camera looks straight down with +y at the top of the image.

Action `(w, dw)`: a Box of 6 floats `(wx, wy, wz, dwx, dwy, dwz)`; z is ignored (fixed
height, as in the paper). Semantics, in order:
  1. pick: the cube whose centre is within `pick_threshold` of `w` (x, y); none -> no-op.
  2. place: snap `w + dw` to the nearest cell; a target outside the grid (further than half
     a cell beyond the outer cells) or occupied by another cube -> no-op.
A constraint holds when its cube is within `success_threshold` of its goal position.
"""
from __future__ import annotations

import os
import sys
from dataclasses import asdict, dataclass

import numpy as np
from gymnasium import spaces

from .common import RearrangeEnv, check_index, check_integer, check_number, check_task, constrained_count, horizon


def _import_pybullet_quietly():
    """`import pybullet` without the "pybullet build time: ..." line its C extension writes to
    file descriptor 2 on import (in a notebook it is the first output, in a red stderr box).
    fd 2 points at /dev/null for the import only and is restored afterwards; a failed import
    still raises its ImportError."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    sys.stderr.flush()
    try:
        saved, devnull = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    except OSError:                      # no usable fd 2: import as is
        import pybullet  # local: this function is the import, with fd 2 silenced
        return pybullet
    try:
        os.dup2(devnull, 2)
        import pybullet  # local: this function is the import, with fd 2 silenced
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
    return pybullet


pb = _import_pybullet_quietly()

# Eight colours far apart in RGB, so up to 8 cubes are always distinguishable.
PALETTE = np.array([
    [0.90, 0.10, 0.10],  # red
    [0.10, 0.75, 0.15],  # green
    [0.15, 0.30, 0.95],  # blue
    [0.95, 0.85, 0.10],  # yellow
    [0.85, 0.15, 0.85],  # magenta
    [0.10, 0.85, 0.90],  # cyan
    [0.98, 0.55, 0.05],  # orange
    [0.98, 0.98, 0.98],  # white
], dtype=np.float32)
COLOR_NAMES = ("red", "green", "blue", "yellow", "magenta", "cyan", "orange", "white")
FLOOR_RGB = (0.35, 0.35, 0.38)


class GridTask:
    """What a cube-grid config derives from its fields (num_objects, goal, num_constrained,
    grid_size, cell): the constrained count and the grid's half width."""

    @property
    def constrained(self) -> int:
        return constrained_count(self)

    @property
    def half_extent(self) -> float:
        """Half the grid's width: cells sit at +-(i + 0.5) * cell around the origin."""
        return self.grid_size * self.cell / 2


@dataclass(frozen=True)
class BlockRearrangeConfig(GridTask):
    """Everything that defines a block-rearrange task distribution (stored with data)."""

    num_objects: int = 4
    goal: str = "complete"            # "complete": every cube moves; "partial": a subset
    num_constrained: int | None = None  # partial goals: how many cubes are constrained
    horizon_multiplier: float = 4.0   # horizon = ceil(multiplier x minimum steps)
    action_noise: float = 0.0         # std (m) of Gaussian noise added to (w, dw) each step
    grid_size: int = 4                # cells per side: |S| = grid_size ** 2
    cell: float = 0.1                 # cell pitch (m)
    cube: float = 0.06                # cube edge (m)
    pick_threshold: float = 0.05      # max |w - centre| (x, y) to pick a cube
    success_threshold: float = 0.05   # max |position - goal| for a satisfied constraint
    image_size: int = 64

    def __post_init__(self):
        check_task(self, max_objects=len(PALETTE))
        check_integer(self, "grid_size", 1)
        for name in ("cell", "cube", "pick_threshold", "success_threshold"):
            check_number(self, name)
        cells = self.grid_size ** 2
        if 2 * self.constrained > cells:
            raise ValueError(
                f"{self.constrained} constrained cubes need {2 * self.constrained} distinct "
                f"cells (start and goal) but the grid has {cells}")


class CubeGrid(RearrangeEnv):
    """What the two PyBullet envs share: a grid of cells, k cubes in PALETTE's colours on a
    floor, the (w, dw) action space, a TinyRenderer camera and the DIRECT client. A subclass
    sets `config` (with grid_size, cell, cube, num_objects, image_size, half_extent) and
    provides `_camera() -> (view, projection)`; `_light` is the renderer's light direction
    (None: PyBullet's default)."""

    _light = None

    def _setup(self, render_mode: str | None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        cfg = self.config
        g = cfg.grid_size
        coords = (np.arange(g) - (g - 1) / 2) * cfg.cell
        # cells[i] = (x, y) of cell i, row-major from the bottom-left.
        self.cells = np.stack(np.meshgrid(coords, coords, indexing="xy"), -1).reshape(-1, 2)
        self.cells = self.cells.astype(np.float32)

        # w spans the grid; dw spans twice that, so off-grid targets are reachable.
        r = cfg.half_extent
        self.action_space = spaces.Box(
            low=np.array([-r, -r, 0.0, -2 * r, -2 * r, -0.1], np.float32),
            high=np.array([r, r, 0.1, 2 * r, 2 * r, 0.1], np.float32), dtype=np.float32)
        img = spaces.Box(0, 255, (cfg.image_size, cfg.image_size, 3), np.uint8)
        self.observation_space = spaces.Dict({"image": img, "goal": img})

        self._client = pb.connect(pb.DIRECT)
        c = self._client
        floor = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[0.5, 0.5, 0.005],
                                     rgbaColor=[*FLOOR_RGB, 1], physicsClientId=c)
        pb.createMultiBody(0, -1, floor, basePosition=[0, 0, -0.005], physicsClientId=c)
        self._bodies = []
        for i in range(cfg.num_objects):
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=[cfg.cube / 2] * 3,
                                       rgbaColor=[*PALETTE[i], 1], physicsClientId=c)
            self._bodies.append(pb.createMultiBody(0, -1, vis, physicsClientId=c))
        self._view, self._proj = self._camera()
        self._colors = PALETTE[: cfg.num_objects].copy()
        self._goal_image = self._image = None
        self._steps = 0

    def _camera(self):
        raise NotImplementedError

    def _render(self):
        """One TinyRenderer pass -> (H, W, 3) uint8 image and (k, H, W) bool masks."""
        s = self.config.image_size
        light = {} if self._light is None else {"lightDirection": self._light}
        _, _, rgba, _, seg = pb.getCameraImage(
            s, s, self._view, self._proj, shadow=0, renderer=pb.ER_TINY_RENDERER,
            physicsClientId=self._client, **light)
        rgb = np.asarray(rgba, np.uint8).reshape(s, s, 4)[..., :3].copy()
        seg = np.asarray(seg).reshape(s, s)
        masks = seg[None] == np.asarray(self._bodies)[:, None, None]
        return rgb, masks

    def _recolour(self, rng) -> None:
        """k distinct colours of PALETTE for this episode's cubes."""
        colours = rng.choice(len(PALETTE), size=self.config.num_objects, replace=False)
        self._colors = PALETTE[colours].copy()
        for b, rgb in zip(self._bodies, self._colors):
            pb.changeVisualShape(b, -1, rgbaColor=[*rgb, 1], physicsClientId=self._client)

    def _closed(self) -> bool:
        return getattr(self, "_client", None) is None

    def close(self):
        if getattr(self, "_client", None) is not None:
            pb.disconnect(physicsClientId=self._client)
            self._client = None


class BlockRearrange(CubeGrid):
    """Goal-conditioned block rearrangement with image observations (see module docstring).

    Observation: {"image": (64, 64, 3) uint8, "goal": (64, 64, 3) uint8}.
    info: ground truth for metrics and the oracle only (no learned agent may read it):
      positions (k, 3), colors (k, 3), types (k, 3) what a cube is (= its colour),
      goal_positions (k, 3), constrained (k,) bool,
      masks (k, H, W) bool per-object segmentation, satisfied (k,) bool, moved (int,
      -1 for a no-op), picked (int: the cube the pick found, -1 for none; a refused place
      picks one and moves none), min_steps, horizon, is_success.
    """

    def __init__(self, num_objects: int = 4, goal: str = "complete", num_constrained=None,
                 horizon_multiplier: float = 4.0, action_noise: float = 0.0,
                 render_mode: str | None = None, **kwargs):
        self.config = BlockRearrangeConfig(num_objects=num_objects, goal=goal,
                                           num_constrained=num_constrained,
                                           horizon_multiplier=horizon_multiplier,
                                           action_noise=action_noise, **kwargs)
        self._setup(render_mode)
        self._cell_of = np.zeros(self.config.num_objects, np.int64)   # current cell of each cube
        self._goal_cell = np.zeros(self.config.num_objects, np.int64)
        self._constrained = np.zeros(self.config.num_objects, bool)

    # ----------------------------------------------------------------- scene
    def _camera(self):
        """Near-orthographic top-down view: a far camera with a narrow field of view."""
        cfg = self.config
        dist = 3.0
        margin = cfg.half_extent + 0.04
        fov = float(np.degrees(2 * np.arctan(margin / (dist - cfg.cube))))
        view = pb.computeViewMatrix([0, 0, dist], [0, 0, 0], [0, 1, 0])
        return view, pb.computeProjectionMatrixFOV(fov, 1.0, dist - 0.5, dist + 0.5)

    def _place(self, cells_of, visible=None):
        cfg = self.config
        for i, b in enumerate(self._bodies):
            if visible is not None and not visible[i]:
                xyz = [10.0, 10.0, -5.0]  # out of the camera's frustum
            else:
                x, y = self.cells[cells_of[i]]
                xyz = [float(x), float(y), cfg.cube / 2]
            pb.resetBasePositionAndOrientation(b, xyz, [0, 0, 0, 1], physicsClientId=self._client)

    # ------------------------------------------------------------------- API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._check_open("reset")
        super().reset(seed=seed)
        cfg, rng = self.config, self.np_random
        k, m = cfg.num_objects, cfg.constrained
        self._recolour(rng)
        # Start cells for all k cubes plus m goal cells, all distinct: goals avoid starts.
        cells = rng.choice(len(self.cells), size=k + m, replace=False)
        self._cell_of = cells[:k].copy()
        self._constrained = np.zeros(k, bool)
        self._constrained[rng.choice(k, size=m, replace=False)] = True
        self._goal_cell = self._cell_of.copy()
        self._goal_cell[self._constrained] = cells[k:]
        self.min_steps = int(m)
        self.horizon = horizon(cfg, self.min_steps)
        self._steps = 0
        # The goal image shows only the constrained cubes, at their goal cells.
        self._place(self._goal_cell, visible=self._constrained)
        self._goal_image, self._goal_masks = self._render()
        self._place(self._cell_of)
        return self._observe(moved=-1)

    def _after_move(self) -> None:
        self._place(self._cell_of)

    # --------------------------------------------------------------- helpers
    def _apply(self, action: np.ndarray) -> int:
        """Pick and move; return (the picked cube or -1, the moved cube or -1 for a no-op)."""
        cfg = self.config
        w, target = action[:2], action[:2] + action[3:5]
        centres = self.cells[self._cell_of]
        dist = np.linalg.norm(centres - w, axis=1)
        picked = int(np.argmin(dist))
        if dist[picked] > cfg.pick_threshold:
            return -1, -1
        if np.any(np.abs(target) > cfg.half_extent):
            return picked, -1  # off-grid
        cell = int(np.argmin(np.linalg.norm(self.cells - target, axis=1)))
        if cell in self._cell_of:
            return picked, -1  # occupied (including by the picked cube itself)
        self._cell_of[picked] = cell
        return picked, picked

    def _observe(self, moved: int, picked: int = -1):
        self._image, masks = self._render()
        cfg = self.config
        z = np.full((cfg.num_objects, 1), cfg.cube / 2, np.float32)
        pos = np.concatenate([self.cells[self._cell_of], z], 1)
        goal = np.concatenate([self.cells[self._goal_cell], z], 1)
        satisfied = np.linalg.norm(pos - goal, axis=1) <= cfg.success_threshold
        info = {
            "positions": pos, "goal_positions": goal, "colors": self._colors.copy(),
            "types": self._colors.copy(), "constrained": self._constrained.copy(), "masks": masks,
            "goal_masks": self._goal_masks.copy(), "satisfied": satisfied, "moved": int(moved), "picked": int(picked),
            "min_steps": self.min_steps, "horizon": self.horizon, "steps": self._steps,
            "is_success": bool(np.all(satisfied[self._constrained])),
        }
        return {"image": self._image.copy(), "goal": self._goal_image.copy()}, info

    # ------------------------------------------------------- for data + tests
    def free_cells(self) -> np.ndarray:
        return np.setdiff1d(np.arange(len(self.cells)), self._cell_of)

    def pick_and_move(self, obj: int, cell: int) -> np.ndarray:
        """The action that moves cube `obj` to grid cell `cell` (no noise): (w, dw)."""
        obj = check_index("obj", obj, self.config.num_objects)
        cell = check_index("cell", cell, len(self.cells))
        w = self.cells[self._cell_of[obj]]
        dw = self.cells[cell] - w
        h = self.config.cube / 2
        return np.array([w[0], w[1], h, dw[0], dw[1], 0.0], np.float32)

    def random_pick_and_move(self, rng: np.random.Generator) -> np.ndarray:
        """A 'video demonstration' action: a random cube to a random free cell."""
        obj = int(rng.integers(self.config.num_objects))
        return self.pick_and_move(obj, int(rng.choice(self.free_cells())))

    def describe(self) -> dict:
        return {"env": "block-rearrange", **asdict(self.config)}
