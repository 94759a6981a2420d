"""Block-stacking (Table 4's third environment): cubes in stacks on a 4x4 grid; goals are towers.

The objects depend on each other here, which block-rearrange and robogym-rearrange never
ask of NCS (Appendix F): only the top cube of a stack can be picked, a cube is put on top
of the stack at its target cell, and a tower is built bottom up.

The arena is block-rearrange's: 4x4 cells 10 cm apart, 6 cm cubes in its eight colours,
rendered by PyBullet's TinyRenderer in DIRECT mode. Stacks are at most `max_height` = 3
cubes high, so a cube has 16 x 3 = 48 places (cell, level), the nearest grid to the 47
graph nodes of Table 4. Heights must be visible, so the camera looks down from the front
at `elevation` = 60 degrees instead of straight down: a cube one level up is drawn 3.5 pixels
higher in the 64-pixel image (a row further back: 10 pixels), its lit top face above its darker
front face (a person and a model tell a 2-stack from a 3-stack by the height of the top cube).
From 60 degrees a 2-stack never hides the front face of a cube in the row behind it; a 3-stack
can, and a cube under another that is hidden so has no visible pixel (`info["masks"]` all
False: 1 cube in 107 of the starts and goals of 400 six-cube tasks, 1 in 267 with 5 cubes, none
with 4, which cannot make a 3-stack in front of a covered cube). Higher cameras hide less behind stacks but draw
levels closer together, and from straight above a covered cube is never seen.

Action `(w, dw)`: the Box of block-rearrange (z ignored). Semantics, in order:
  1. pick: the top cube of the stack whose cell centre is within `pick_threshold` of `w`
     (x, y); an empty cell or no cell that close -> no-op. A cube under another cannot be
     picked.
  2. place: snap `w + dw` to the nearest cell and put the cube on top of that stack; a target
     outside the grid, the cube's own cell or a full stack -> no-op.
No physics is simulated: a cube sits exactly on the one below it, so no cube ever floats or
interpenetrates another.

Starts and goals are random configurations in which each cube, dropped in a random order,
lands on a stack with room with probability `stack_probability` = 0.7, else on an empty cell
(at 4 cubes about 56 % of cubes on the floor, 28 % on level 1 and 16 % on level 2; uniform
drops would leave 4 % on level 2, too few for the graph to give those places nodes).
Goals are towers: a goal places every cube (complete) or a subset closed downwards (partial:
a constrained cube's supports in the goal tower are constrained too, so the goal image shows
no floating cube), and a constraint holds when its cube is within `success_threshold` of its
goal position in 3-D, which is its goal cell **and** level (levels are a cube apart, more
than the threshold). `info["min_steps"]` is the exact minimum number of moves (`min_moves`,
an A* search), and the horizon counts from it.
"""
from __future__ import annotations

import heapq
from dataclasses import asdict, dataclass

import numpy as np

from .block_rearrange import PALETTE, CubeGrid, GridTask, pb
from .common import check_index, check_integer, check_number, check_task, horizon

Stacks = tuple[tuple[int, ...], ...]     # per cell, the cubes bottom to top


@dataclass(frozen=True)
class BlockStackingConfig(GridTask):
    """Everything that defines a block-stacking task distribution (stored with data)."""

    num_objects: int = 4
    goal: str = "complete"            # "complete": every cube; "partial": towers of a subset
    num_constrained: int | None = None  # partial goals: how many cubes are constrained
    horizon_multiplier: float = 4.0   # horizon = ceil(multiplier x minimum moves)
    action_noise: float = 0.0         # std (m) of Gaussian noise added to (w, dw) each step
    grid_size: int = 4                # cells per side
    max_height: int = 3               # cubes a stack holds
    cell: float = 0.1                 # cell pitch (m)
    cube: float = 0.06                # cube edge (m): also the height of a level
    pick_threshold: float = 0.05      # max |w - cell centre| (x, y) to pick a stack's top cube
    success_threshold: float = 0.05   # max |position - goal| (3-D) for a satisfied constraint
    stack_probability: float = 0.7    # starts and goals: a cube goes on a stack (not an empty cell)
    elevation: float = 60.0           # camera elevation above the floor (degrees)
    image_size: int = 64

    def __post_init__(self):
        check_task(self, max_objects=len(PALETTE))
        check_integer(self, "grid_size", 1)
        check_integer(self, "max_height", 1)
        for name in ("cell", "cube", "pick_threshold", "success_threshold", "elevation"):
            check_number(self, name)
        check_number(self, "stack_probability", allow_zero=True)
        if not 0 <= self.stack_probability <= 1:
            raise ValueError(f"stack_probability must be in [0, 1], got {self.stack_probability!r}")
        if not self.elevation <= 90:
            raise ValueError(f"elevation must be in (0, 90] degrees, got {self.elevation!r}")
        if not self.success_threshold < self.cube:
            raise ValueError(f"success_threshold must be below the cube's edge {self.cube} (a level), so a cube "
                             f"one level off is not at its goal; got {self.success_threshold!r}")
        if self.num_objects > self.grid_size ** 2 * self.max_height - self.max_height:
            raise ValueError(f"{self.num_objects} cubes leave no room to move on a {self.grid_size}x"
                             f"{self.grid_size} grid of stacks of {self.max_height}")


# ------------------------------------------------------------ the task's combinatorics
def legal_moves(stacks: Stacks, max_height: int):
    """Every move (cube, from cell, to cell) of a configuration: a top cube onto another stack
    that has room."""
    for src, stack in enumerate(stacks):
        if stack:
            for dst, other in enumerate(stacks):
                if dst != src and len(other) < max_height:
                    yield stack[-1], src, dst


def apply_move(stacks: Stacks, src: int, dst: int) -> Stacks:
    """The configuration after moving the top cube of stack `src` onto stack `dst`."""
    out = list(stacks)
    out[dst] = stacks[dst] + (stacks[src][-1],)
    out[src] = stacks[src][:-1]
    return tuple(out)


def placed(stacks: Stacks, goal: dict[int, tuple[int, int]]) -> set[int]:
    """The constrained cubes in their final place: at their goal (cell, level) on cubes that can
    all stay (none is constrained elsewhere, none holds another cube's goal place). Any other
    constrained cube must move at least once. In a goal closed downwards (the env's) every cube
    under a placed cube is placed; an unconstrained support is fine in any other goal."""
    owner = {place: cube for cube, place in goal.items()}
    done = set()
    for cell, stack in enumerate(stacks):
        for level, cube in enumerate(stack):
            if goal.get(cube, (cell, level)) != (cell, level) or owner.get((cell, level), cube) != cube:
                break
            if cube in goal:
                done.add(cube)
    return done


def min_moves(stacks: Stacks, goal: dict[int, tuple[int, int]], max_height: int) -> int:
    """The minimum number of moves that puts every cube of `goal` (cube -> (cell, level)) in
    place, by A* search. The heuristic, the number of constrained cubes not yet `placed`, is
    consistent (a move places or unplaces at most the cube it moves), so the first goal
    popped is optimal."""
    start = tuple(tuple(s) for s in stacks)
    frontier, best = [(len(goal) - len(placed(start, goal)), 0, start)], {start: 0}
    while frontier:
        f, depth, state = heapq.heappop(frontier)     # ties: the deeper state first (depth is -g)
        g = -depth
        if f == g:
            return g
        if best.get(state, g) < g:
            continue
        for _, src, dst in legal_moves(state, max_height):
            nxt = apply_move(state, src, dst)
            if best.get(nxt, g + 2) > g + 1:
                best[nxt] = g + 1
                heapq.heappush(frontier, (g + 1 + len(goal) - len(placed(nxt, goal)), -(g + 1), nxt))
    raise ValueError(f"no sequence of moves reaches the goal {goal} from {stacks}")


def random_stacks(rng: np.random.Generator, num_objects: int, cells: int, max_height: int,
                  stack_probability: float) -> Stacks:
    """Cubes 0..k-1 dropped one by one in a random order: on a random stack that has room with
    probability `stack_probability` (when there is one), else on a random empty cell."""
    stacks: list[list[int]] = [[] for _ in range(cells)]
    for cube in rng.permutation(num_objects):
        partial = [c for c in range(cells) if 0 < len(stacks[c]) < max_height]
        empty = [c for c in range(cells) if not stacks[c]]
        pool = partial if partial and (rng.random() < stack_probability or not empty) else empty
        stacks[int(rng.choice(pool))].append(int(cube))
    return tuple(tuple(s) for s in stacks)


def where(stacks: Stacks) -> dict[int, tuple[int, int]]:
    """cube -> (cell, level) of a configuration."""
    return {cube: (cell, level) for cell, stack in enumerate(stacks) for level, cube in enumerate(stack)}


class BlockStacking(CubeGrid):
    """Goal-conditioned block stacking with image observations (see module docstring).

    Observation: {"image": (64, 64, 3) uint8, "goal": (64, 64, 3) uint8}.
    info: block-rearrange's keys (ground truth for metrics and the oracle only):
      positions (k, 3) with z = (level + 0.5) x cube, goal_positions (k, 3), colors, types,
      constrained (k,) bool, masks (k, H, W) visible pixels of each cube, goal_masks,
      satisfied (k,) bool, moved, picked, min_steps (exact), horizon, steps, is_success;
      and levels (k,) int, each cube's level (0 on the floor), and goal_levels (k,). An unconstrained
      cube's goal position is its start, as in block-rearrange.
    """

    def __init__(self, num_objects: int = 4, goal: str = "complete", num_constrained=None,
                 horizon_multiplier: float = 4.0, action_noise: float = 0.0,
                 render_mode: str | None = None, **kwargs):
        self.config = BlockStackingConfig(num_objects=num_objects, goal=goal, num_constrained=num_constrained,
                                          horizon_multiplier=horizon_multiplier, action_noise=action_noise,
                                          **kwargs)
        self._setup(render_mode)
        self._stacks: Stacks = tuple(() for _ in self.cells)
        self._goal_place: dict[int, tuple[int, int]] = {}
        self._goal_positions = np.zeros((self.config.num_objects, 3), np.float32)
        self._constrained = np.zeros(self.config.num_objects, bool)

    # ----------------------------------------------------------------- scene
    _light = [0.4, -1.0, 2.0]           # from the front and above: top faces lit, front faces darker

    def _camera(self):
        cfg = self.config
        # A far camera in front of the grid (-y), `elevation` degrees up, aimed at the middle
        # of the tallest towers; the field of view fits the grid and stacks of max_height.
        dist, el = 3.0, np.radians(cfg.elevation)
        top = cfg.max_height * cfg.cube
        target = np.array([0.0, 0.0, top / 2])
        eye = target + dist * np.array([0.0, -np.cos(el), np.sin(el)])
        view = pb.computeViewMatrix(eye.tolist(), target.tolist(), [0, 0, 1])
        # the scene's extent seen from the camera: the grid's depth foreshortened plus the towers
        r = cfg.half_extent + 0.03
        vertical = r * np.sin(el) + top / 2 * np.cos(el) + 0.01
        fov = float(np.degrees(2 * np.arctan(max(r, vertical) / (dist - r))))
        return view, pb.computeProjectionMatrixFOV(fov, 1.0, dist - 1.0, dist + 1.0)

    def _place(self, stacks: Stacks, visible=None):
        cfg = self.config
        at = where(stacks)
        for i, b in enumerate(self._bodies):
            if i not in at or (visible is not None and not visible[i]):
                xyz = [10.0, 10.0, -5.0]           # out of the camera's frustum
            else:
                cell, level = at[i]
                x, y = self.cells[cell]
                xyz = [float(x), float(y), (level + 0.5) * cfg.cube]
            pb.resetBasePositionAndOrientation(b, xyz, [0, 0, 0, 1], physicsClientId=self._client)

    # ------------------------------------------------------------------- API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._check_open("reset")
        super().reset(seed=seed)
        cfg, rng = self.config, self.np_random
        k, m = cfg.num_objects, cfg.constrained
        self._recolour(rng)
        cells = len(self.cells)
        # the goal: a random configuration; its constrained cubes are the first m of a random
        # bottom-up order (a cube joins once the cube under it has), so the set is closed downwards
        goal = random_stacks(rng, k, cells, cfg.max_height, cfg.stack_probability)
        goal_at = where(goal)
        order = [int(c) for c in rng.permutation(k)]
        chosen: list[int] = []
        while len(chosen) < m:
            cube = next(c for c in order if c not in chosen and
                        (goal_at[c][1] == 0 or goal[goal_at[c][0]][goal_at[c][1] - 1] in chosen))
            chosen.append(cube)
        self._constrained = np.zeros(k, bool)
        self._constrained[chosen] = True
        self._goal_place = {c: goal_at[c] for c in chosen}
        # the start: a random configuration in which no constrained cube is at its goal place
        # (every constrained cube must move, as in block-rearrange)
        while True:
            start = random_stacks(rng, k, cells, cfg.max_height, cfg.stack_probability)
            at = where(start)
            if all(at[c] != self._goal_place[c] for c in chosen):
                break
        self._stacks = start
        # an unconstrained cube's goal position is its start, as in block-rearrange (the goal
        # image does not show it)
        self._goal_positions = self._positions({**where(start), **self._goal_place})
        self.min_steps = min_moves(start, self._goal_place, cfg.max_height)
        self.horizon = horizon(cfg, self.min_steps)
        self._steps = 0
        self._place(goal, visible=self._constrained)
        self._goal_image, self._goal_masks = self._render()
        self._place(self._stacks)
        return self._observe(moved=-1)

    def _after_move(self) -> None:
        self._place(self._stacks)

    def _apply(self, action: np.ndarray):
        """Pick the top cube at w and put it on the stack nearest w + dw: (picked, moved)."""
        cfg = self.config
        w, target = action[:2], action[:2] + action[3:5]
        dist = np.linalg.norm(self.cells - w, axis=1)
        src = int(np.argmin(dist))
        if dist[src] > cfg.pick_threshold or not self._stacks[src]:
            return -1, -1
        picked = self._stacks[src][-1]
        if np.any(np.abs(target) > cfg.half_extent):
            return picked, -1                                      # off-grid
        dst = int(np.argmin(np.linalg.norm(self.cells - target, axis=1)))
        if dst == src or len(self._stacks[dst]) >= cfg.max_height:
            return picked, -1                                      # its own cell, or a full stack
        self._stacks = apply_move(self._stacks, src, dst)
        return picked, picked

    def _positions(self, places: dict[int, tuple[int, int]]) -> np.ndarray:
        cfg = self.config
        pos = np.zeros((cfg.num_objects, 3), np.float32)
        for cube, (cell, level) in places.items():
            pos[cube] = (*self.cells[cell], (level + 0.5) * cfg.cube)
        return pos

    def _observe(self, moved: int, picked: int = -1):
        self._image, masks = self._render()
        at = where(self._stacks)
        pos = self._positions(at)
        goal = self._goal_positions.copy()
        satisfied = np.linalg.norm(pos - goal, axis=1) <= self.config.success_threshold
        info = {
            "positions": pos, "goal_positions": goal, "colors": self._colors.copy(),
            "types": self._colors.copy(), "constrained": self._constrained.copy(), "masks": masks,
            "goal_masks": self._goal_masks.copy(), "satisfied": satisfied, "moved": int(moved),
            "picked": int(picked), "min_steps": self.min_steps, "horizon": self.horizon, "steps": self._steps,
            "is_success": bool(np.all(satisfied[self._constrained])),
            "levels": np.array([at[i][1] for i in range(len(pos))], np.int64),
            "goal_levels": np.round(goal[:, 2] / self.config.cube - 0.5).astype(np.int64),
        }
        return {"image": self._image.copy(), "goal": self._goal_image.copy()}, info

    # ------------------------------------------------------- for data + tests
    @property
    def stacks(self) -> Stacks:
        """The configuration: per cell, the cubes bottom to top."""
        return self._stacks

    def tops(self) -> list[int]:
        """The cubes that can be picked (the top of every stack)."""
        return [s[-1] for s in self._stacks if s]

    def open_cells(self, cube: int | None = None) -> np.ndarray:
        """The cells a cube can be put on: stacks with room, other than `cube`'s own."""
        own = where(self._stacks)[cube][0] if cube is not None else -1
        return np.array([c for c, s in enumerate(self._stacks)
                         if len(s) < self.config.max_height and c != own], np.int64)

    def pick_and_move(self, obj: int, cell: int) -> np.ndarray:
        """The action that moves cube `obj` onto the stack at grid cell `cell` (no noise);
        it moves the cube only if the cube is on top and the stack has room."""
        obj = check_index("obj", obj, self.config.num_objects)
        cell = check_index("cell", cell, len(self.cells))
        w = self.cells[where(self._stacks)[obj][0]]
        dw = self.cells[cell] - w
        return np.array([w[0], w[1], self.config.cube / 2, dw[0], dw[1], 0.0], np.float32)

    def random_pick_and_move(self, rng: np.random.Generator) -> np.ndarray:
        """A 'video demonstration' action: a random top cube onto a random stack with room."""
        obj = int(rng.choice(self.tops()))
        return self.pick_and_move(obj, int(rng.choice(self.open_cells(obj))))

    def describe(self) -> dict:
        return {"env": "block-stacking", **asdict(self.config)}
