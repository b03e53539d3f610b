"""Throughput of BenchMARL's MAPPO / IPPO on a benchmark task, one torch thread (one core).

Times the three parts of a leaderboard unit (`agent_envs.training.learners.benchmarl_runs`):
collecting frames (TorchRL's PettingZooWrapper around swarm_v0, the policy's forward), the PPO
updates (per minibatch of `minibatch_size` frames x N agents), and one validation episode
(`validation_cost`), so that a frame budget can be sized to a wall-time limit:

    time ~ frames / collect_fps + batches x minibatch_iters x (batch / minibatch) x update_s
           + validations x episodes x validation_s

    nice -n 5 python benchmarks/benchmarl_throughput.py --task agent_envs/StiffSwarm-v0

Needs the `marl` extra. About a minute per algorithm at N = 100 on a loaded core.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from agent_envs.training.learners.benchmarl_runs import (
    ALGORITHMS,
    MarlRun,
    ValidationCallback,
    build_experiment,
    validation_cost,
)


class Timer(ValidationCallback):
    """Wall and CPU time (this process) at the end of the collection and of the updates."""

    def __init__(self, run: MarlRun) -> None:
        super().__init__(run)
        self.marks: list[tuple[float, float]] = []

    def on_batch_collected(self, batch) -> None:
        self.marks.append((time.perf_counter(), time.process_time()))

    def on_train_end(self, training_td, group: str) -> None:
        self.marks.append((time.perf_counter(), time.process_time()))


def measure(task: str, algorithm: str, frames: int, iters: int) -> dict:
    """Collected frames per second, seconds per minibatch update and per validation episode,
    in wall time and in this process's CPU time (what one unloaded core would take)."""
    import torch

    torch.set_num_threads(1)
    run = MarlRun(task, algorithm, 0, frames=frames, batch_frames=frames, minibatch_iters=iters)
    timer = Timer(run)
    with tempfile.TemporaryDirectory() as folder:
        experiment = build_experiment(run, Path(folder), [timer])
        start = (time.perf_counter(), time.process_time())
        experiment.run()
    collected, trained = timer.marks
    updates = iters * -(-frames // run.minibatch_size)
    one = MarlRun(task, algorithm, 0, validation_episodes=1)
    begin = (time.perf_counter(), time.process_time())
    validation_cost(experiment.policy, one)
    end = (time.perf_counter(), time.process_time())
    row = {"algorithm": algorithm, "frames": frames, "updates": updates}
    for i, clock in enumerate(("wall", "cpu")):
        row[f"collect_fps_{clock}"] = frames / (collected[i] - start[i])
        row[f"update_seconds_{clock}"] = (trained[i] - collected[i]) / updates
        row[f"validation_episode_seconds_{clock}"] = end[i] - begin[i]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="agent_envs/StiffSwarm-v0")
    parser.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS))
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--minibatch-iters", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    rows = [measure(args.task, a, args.frames, args.minibatch_iters) for a in args.algorithms]
    result = {"task": args.task, "load_average": os.getloadavg(), "rows": rows}
    print(json.dumps(result, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
