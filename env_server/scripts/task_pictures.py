"""Frame strips of the paper's tasks for docs/tasks.md, rendered through the server's Render RPC.

    ../.venv/bin/python scripts/task_pictures.py [OUT_DIR]   # default: docs/tasks

Starts a local env_server, and for each task makes a session, resets it with seed 0,
acts for one stretch of an episode and renders four frames across it (the first, two
between and the last; an episode that ends early is shown at its end), side by side
in one palette PNG. The policy is stated per task below: scripted for DST (the 8.2
treasure) and humanoid-mocap (the zero action, which drives every joint to the middle
of its range), uniformly random actions (seed 0) for the others, which shows the scene
and the task's objects, not a solution.
"""

from __future__ import annotations

import pathlib
import subprocess
import sys

import numpy as np
from PIL import Image

from env_server.client import RemoteVectorEnv

HERE = pathlib.Path(__file__).resolve().parent
WIDTH, HEIGHT, FRAMES, GAP = 240, 180, 4, 4
#: task -> (steps rendered over, scripted actions or None for random ones)
TASKS = {
    "dst": (3, [1, 2, 2]),
    "humanoid-run": (60, None),
    "shadow-touch": (40, None),
    "shadow-turn": (40, None),
    "shadow-orient": (40, None),
    "humanoid-mocap": (15, [np.zeros(56, np.float32)] * 15),
    "sawyer-peg": (60, None),
}


def strip(address: str, env_id: str, steps: int, script: list[int] | None) -> Image.Image:
    # Autoreset off, so the frames after an episode's end show how it ended.
    with RemoteVectorEnv(address, env_id, 1, seed=0, autoreset="disabled") as env:
        env.reset()
        env.session_spec.action_space.seed(0)
        at = set(np.linspace(0, steps, FRAMES).round().astype(int).tolist())
        frames = [env.render(width=WIDTH, height=HEIGHT)[0]] if 0 in at else []
        ended = False
        for t in range(1, steps + 1):
            if not ended:
                action = script[t - 1] if script else env.session_spec.action_space.sample()
                _, _, terminated, truncated, _ = env.step(np.asarray(action)[None])
                ended = bool(terminated[0] or truncated[0])
            if t in at:
                frames.append(env.render(width=WIDTH, height=HEIGHT)[0])
    canvas = np.full((HEIGHT, FRAMES * WIDTH + (FRAMES - 1) * GAP, 3), 255, np.uint8)
    for i, frame in enumerate(frames):
        canvas[:, i * (WIDTH + GAP) : i * (WIDTH + GAP) + WIDTH] = frame
    return Image.fromarray(canvas).quantize(colors=96, method=Image.Quantize.MEDIANCUT)


def main() -> None:
    out = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else HERE.parent.parent / "docs" / "tasks"
    out.mkdir(parents=True, exist_ok=True)
    server = subprocess.Popen(
        [sys.executable, "-m", "env_server", "--port", "0", "--log-level", "WARNING"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        address = server.stdout.readline().split()[1]
        for env_id, (steps, script) in TASKS.items():
            path = out / f"{env_id}.png"
            strip(address, env_id, steps, script).save(path, optimize=True)
            print(f"{path} ({path.stat().st_size // 1024} KB)")
    finally:
        server.terminate()
        server.wait()


if __name__ == "__main__":
    main()
