"""Deep Sea Treasure (Vamplew et al. 2011; the MO-MPO paper, appendix A.2/B.1).

A submarine starts at the top-left cell of an 11 x 10 grid (rows x columns) and moves
up/right/down/left. Each column holds one treasure; the cells below it are sea floor.
Moving off the grid or into the sea floor leaves the submarine where it is. Picking up
a treasure ends the episode; 200 steps end it by truncation.

## Reward Space
0: time, -1 on every step (the treasure step included)
1: treasure, the treasure's value on pickup, else 0

## Source
Treasure values are Yang et al. (2019)'s convex map, which the paper uses.
Actions follow the paper: 0 up, 1 right, 2 down, 3 left (MO-Gymnasium's
deep-sea-treasure-v0 orders them 0 up, 1 down, 2 left, 3 right and adds an 11th column).
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np

from env_server.task import Objective, StepOutcome, Task

ROWS, COLS = 11, 10
#: (row, col) -> value; every cell below a treasure in its column is sea floor.
TREASURES: dict[tuple[int, int], float] = {
    (1, 0): 0.7,
    (2, 1): 8.2,
    (3, 2): 11.5,
    (4, 3): 14.0,
    (4, 4): 15.1,
    (4, 5): 16.1,
    (7, 6): 19.6,
    (7, 7): 20.3,
    (9, 8): 22.4,
    (10, 9): 23.7,
}
#: Action -> (d_row, d_col): 0 up, 1 right, 2 down, 3 left.
MOVES: tuple[tuple[int, int], ...] = ((-1, 0), (0, 1), (1, 0), (0, -1))
_FLOOR_BELOW = {col: row for (row, col) in TREASURES}
#: Frame colours (RGB).
SEA, FLOOR, GRID, GOLD, SUBMARINE, MARGIN = (
    (24, 92, 160),
    (92, 64, 40),
    (16, 60, 110),
    (240, 196, 40),
    (230, 60, 40),
    (10, 20, 30),
)


def is_sea_floor(row: int, col: int) -> bool:
    """True for cells strictly below the treasure of their column."""
    return row > _FLOOR_BELOW[col]


class DeepSeaTreasure(Task):
    """11 x 10 Deep Sea Treasure with objectives [time, treasure]."""

    description = "Deep Sea Treasure 11x10 (paper B.1): [time, treasure], 4 actions, 200 steps"
    objectives = (
        Objective("time", "-1 every step, the treasure step included", -1.0, -1.0),
        Objective("treasure", "the treasure's value on pickup, else 0", 0.0, max(TREASURES.values())),
    )
    max_episode_steps = 200
    render_fps = 4.0  # a grid world has no real time; slow enough to follow each move

    def __init__(self) -> None:
        self.observation_space = gymnasium.spaces.Box(
            np.zeros(2, np.float32), np.array([ROWS - 1, COLS - 1], np.float32), (2,), np.float32
        )
        self.action_space = gymnasium.spaces.Discrete(4)
        self._pos = (0, 0)
        self._obs = np.zeros(2, np.float32)
        self._reward = np.zeros(2, np.float32)

    def _observe(self) -> np.ndarray:
        self._obs[0], self._obs[1] = self._pos
        return self._obs

    def reset(self, seed: int | None = None) -> tuple[Any, dict[str, Any]]:
        # The dynamics are deterministic; the seed has nothing to randomise.
        self._pos = (0, 0)
        return self._observe(), {}

    def render(self, width: int, height: int, camera: str) -> np.ndarray:
        """The grid drawn with numpy (no OpenGL): sea, sea floor, treasures (gold, larger
        for larger values) and the submarine (red), centred with square cells."""
        frame = np.empty((height, width, 3), np.uint8)
        frame[:] = MARGIN
        cell = max(1, min(width // COLS, height // ROWS))
        top, left = (height - cell * ROWS) // 2, (width - cell * COLS) // 2
        top, left = max(top, 0), max(left, 0)
        top_value = max(TREASURES.values())
        for row in range(ROWS):
            for col in range(COLS):
                y, x = top + row * cell, left + col * cell
                block = frame[y : y + cell, x : x + cell]
                block[:] = FLOOR if is_sea_floor(row, col) else SEA
                if cell >= 6:  # grid lines only where they leave room for the cell
                    block[-1, :] = block[:, -1] = GRID
                value = TREASURES.get((row, col))
                if value is not None:
                    inset = int(cell * (0.4 - 0.3 * value / top_value))
                    block[inset : cell - inset, inset : cell - inset] = GOLD
                if (row, col) == self._pos:
                    r = np.arange(cell) - (cell - 1) / 2
                    disk = r[:, None] ** 2 + r[None, :] ** 2 <= (0.38 * cell) ** 2
                    block[disk] = SUBMARINE
        return frame

    def step(self, action: Any) -> StepOutcome:
        d_row, d_col = MOVES[int(action)]
        row, col = self._pos[0] + d_row, self._pos[1] + d_col
        if 0 <= row < ROWS and 0 <= col < COLS and not is_sea_floor(row, col):
            self._pos = (row, col)
        treasure = TREASURES.get(self._pos, 0.0)
        self._reward[0] = -1.0
        self._reward[1] = treasure
        return StepOutcome(self._observe(), self._reward, self._pos in TREASURES, False)
