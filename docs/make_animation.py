"""Render the GIF on the docs' front page: one swarm, one seed, four controllers side by side.

    python docs/make_animation.py                   # writes docs/figures/swarm_controllers.gif
    python docs/make_animation.py --n-agents 20 --seed 3 --out /tmp/swarm.gif

Each panel is the env's own ``render_mode="rgb_array"`` frame (`agent_envs.envs.rendering`:
every agent's path-mean position against time, a dot at its current position, the target
dashed; the first frame shows the start) after each step of
`agent_envs/Swarm-v0` on the same seed, under

- the optimal open-loop control (`agent_envs.baselines.OptimalController`: the plan solved
  from the episode's start, then replayed; needs torch, the ``train`` extra),
- `apg`, the learned feedback law (`agent_envs.training.learners.apg`, trained here on the env's own
  kwargs for 150 iterations, seed 0: some 20 s on one core),
- the proportional controller beta (xbar - E x_k) until the turnpike time, then 0,
- the paper's turnpike controller (the cheap control `eq:cheap_ctr`, which also cancels the
  interaction drift, until the turnpike time of `eq:tptime`, then 0).

The caption under each panel is the discrete cost accrued so far (minus the sum of rewards).
A panel is any entry of `CONTROLLERS`: a name and a callable that takes the env and returns an
object with SB3's ``predict(obs, state)`` (a trained learner's policy can be added that way).
About a minute on two loaded cores with the defaults; the GIF is kept under 2 MB.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
from PIL import Image, ImageDraw, ImageFont

import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)
from agent_envs.baselines import (
    OptimalController,
    ProportionalController,
    TurnpikeController,
)

DEFAULT_OUT = Path(__file__).resolve().parent / "figures" / "swarm_controllers.gif"


def apg_controller(env: gym.Env) -> object:
    """An `apg` law trained for this env (its N and m; 150 iterations, seed 0), as a policy."""
    import tempfile

    from agent_envs.training.learners.apg import train_apg
    from agent_envs.training.learners.apg_config import APGConfig
    from agent_envs.training.learners.apg_policy import load_apg_policy

    base = env.unwrapped
    kwargs = {"n_agents": base.params.n_agents, "n_steps": base.n_steps}
    run = Path(tempfile.mkdtemp(prefix="apg-animation-")) / "run"
    train_apg(APGConfig(env_kwargs=kwargs, iterations=150, progress=False), run)
    return load_apg_policy(run)


CONTROLLERS = {
    "optimal control": OptimalController,
    "apg (learned)": apg_controller,
    "proportional": ProportionalController,
    "turnpike (paper)": TurnpikeController,
}
CAPTION_HEIGHT = 26


def episode_frames(name: str, env_kwargs: dict, seed: int, scale: float) -> list[Image.Image]:
    """The env's rgb_array frames of one episode under one controller, with a cost caption."""
    env = gym.make("agent_envs/Swarm-v0", render_mode="rgb_array", **env_kwargs)
    controller = CONTROLLERS[name](env)
    obs, _ = env.reset(seed=seed)
    frames, cost, state, done = [], 0.0, None, False
    while True:
        frames.append(_captioned(env.render(), f"{name}: cost {cost:.3f}", scale))
        if done:
            break
        action, state = controller.predict(obs, state)
        obs, reward, terminated, truncated, _ = env.step(action)
        cost -= float(reward)
        done = terminated or truncated
    env.close()
    return frames


def _captioned(frame: np.ndarray, caption: str, scale: float) -> Image.Image:
    image = Image.fromarray(frame)
    width, height = int(image.width * scale), int(image.height * scale)
    image = image.resize((width, height), Image.LANCZOS)
    canvas = Image.new("RGB", (width, height + CAPTION_HEIGHT), "white")
    canvas.paste(image, (0, 0))
    font = ImageFont.load_default(size=16)
    ImageDraw.Draw(canvas).text((40, height + 3), caption, fill="black", font=font)
    return canvas


def side_by_side(panels: list[list[Image.Image]]) -> list[Image.Image]:
    """One row of panels per frame; a shorter episode holds its last frame."""
    n_frames = max(len(frames) for frames in panels)
    width = sum(frames[0].width for frames in panels)
    height = max(frames[0].height for frames in panels)
    out = []
    for i in range(n_frames):
        row = Image.new("RGB", (width, height), "white")
        x = 0
        for frames in panels:
            frame = frames[min(i, len(frames) - 1)]
            row.paste(frame, (x, 0))
            x += frame.width
        out.append(row)
    return out


def main(argv: list[str] | None = None) -> Path:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-agents", type=int, default=20)
    parser.add_argument("--n-steps", type=int, default=25)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scale", type=float, default=0.6, help="panel size / rendered size")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    env_kwargs = {"n_agents": args.n_agents, "n_steps": args.n_steps}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the turnpike controller's clip notice
        panels = [episode_frames(name, env_kwargs, args.seed, args.scale) for name in CONTROLLERS]
    frames = side_by_side(panels)
    # The last frame (every episode finished) stays on screen longest.
    durations = [150] * (len(frames) - 1) + [2500]
    palette = [f.quantize(colors=64, method=Image.Quantize.MEDIANCUT) for f in frames]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    palette[0].save(
        args.out,
        save_all=True,
        append_images=palette[1:],
        duration=durations,
        loop=0,
        optimize=True,
    )
    size_mb = args.out.stat().st_size / 2**20
    print(f"{args.out}: {len(frames)} frames, {size_mb:.2f} MB")
    return args.out


if __name__ == "__main__":
    main()
