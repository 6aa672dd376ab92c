"""Deep Sea Treasure against MO-Gymnasium's map and its known Pareto front."""

from __future__ import annotations

import collections

import numpy as np
from mo_gymnasium.envs.deep_sea_treasure import deep_sea_treasure as mo_dst

from env_server.envs import dst

UP, RIGHT, DOWN, LEFT = 0, 1, 2, 3


def test_map_matches_mo_gymnasium() -> None:
    reference = mo_dst.DEFAULT_MAP[:, : dst.COLS]
    assert reference.shape == (dst.ROWS, dst.COLS)
    treasures = {(r, c): float(v) for (r, c), v in np.ndenumerate(reference) if v > 0}
    assert treasures == dst.TREASURES
    floor = {(r, c) for (r, c), v in np.ndenumerate(reference) if v == -10}
    ours = {(r, c) for r in range(dst.ROWS) for c in range(dst.COLS) if dst.is_sea_floor(r, c)}
    assert ours == floor


def _shortest_paths() -> dict[tuple[int, int], int]:
    """BFS over our env's own step(): fewest steps from the start to each treasure."""
    task = dst.DeepSeaTreasure()
    start, _ = task.reset()
    start = tuple(int(v) for v in start)
    dist = {start: 0}
    found: dict[tuple[int, int], int] = {}
    queue = collections.deque([start])
    while queue:
        pos = queue.popleft()
        for action in range(4):
            task._pos = pos
            out = task.step(action)
            nxt = tuple(int(v) for v in out.observation)
            if nxt in dist:
                continue
            dist[nxt] = dist[pos] + 1
            if out.terminated:
                found[nxt] = dist[nxt]
            else:
                queue.append(nxt)
    return found


def test_shortest_paths_give_the_convex_front() -> None:
    found = _shortest_paths()
    front = sorted((dst.TREASURES[pos], -steps) for pos, steps in found.items())
    expected = sorted((float(t), float(s)) for t, s in mo_dst.CONVEX_FRONT)
    assert front == expected


def test_hand_written_path() -> None:
    """Right, down x4 is blocked by the floor at column 1 below row 2: walk to 14.0 at (4, 3)."""
    task = dst.DeepSeaTreasure()
    obs, _ = task.reset()
    assert obs.tolist() == [0.0, 0.0] and obs.dtype == np.float32
    path = [UP, LEFT, RIGHT, RIGHT, RIGHT, DOWN, DOWN, DOWN, DOWN]
    rewards = []
    positions = []
    for action in path:
        out = task.step(action)
        rewards.append(out.reward.copy())
        positions.append(tuple(out.observation.tolist()))
        assert not out.truncated
    # Moves off the grid (up, left at the start) leave the submarine in place.
    assert positions[:2] == [(0.0, 0.0), (0.0, 0.0)]
    assert positions[-1] == (4.0, 3.0)
    assert out.terminated
    np.testing.assert_allclose(np.sum(rewards, axis=0), [-9.0, 14.0], rtol=1e-6)
    assert all(r[0] == -1.0 for r in rewards)


def test_sea_floor_blocks() -> None:
    """From (5, 6) and (8, 8) the cell to the left is sea floor (below 16.1 and 20.3): no move."""
    task = dst.DeepSeaTreasure()
    task.reset()
    for pos in [(5, 6), (8, 8)]:
        task._pos = pos
        out = task.step(LEFT)
        assert tuple(out.observation.tolist()) == pos and not out.terminated
        assert out.reward.tolist() == [-1.0, 0.0]
