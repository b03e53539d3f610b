"""CI: with only `pip install agent-envs` (no extras), the core works and imports no torch.

Run from outside the repository so that the installed wheel, not the source tree, is imported.
"""

import subprocess
import sys
import tempfile

import gymnasium as gym
import numpy as np

import agent_envs
from agent_envs import SwarmParams, simulate, swarm_v0
from agent_envs.baselines import ProportionalController

assert "site-packages" in agent_envs.__file__, agent_envs.__file__
try:
    import torch  # noqa: F401
except ImportError:
    pass
else:
    raise SystemExit("torch is installed in the minimal venv: the core must not need it")

env = gym.make("agent_envs/Swarm-v0", n_agents=10, n_steps=5)
obs, _ = env.reset(seed=0)
ctrl = ProportionalController(env)
total = 0.0
for _ in range(5):
    obs, reward, terminated, truncated, info = env.step(ctrl.predict(obs)[0])
    total += reward
assert truncated and total < 0.0
par = swarm_v0.parallel_env(n_agents=4, n_steps=2)
par.reset(seed=0)
par.step({a: par.action_space(a).sample() for a in par.agents})
traj = simulate(SwarmParams(n_agents=8), n_steps=4, n_paths=2, seed=0)
assert not traj.diverged
bad = sorted(m for m in ("torch", "stable_baselines3", "pandas") if m in sys.modules)
assert not bad, bad

# The command line: the core-only subcommand works, the others say which extra to install.
cli = [sys.executable, "-m", "agent_envs.training.commands.cli"]
with tempfile.TemporaryDirectory() as tmp:
    done = subprocess.run(
        [*cli, "reproduce", "uncontrolled", "--n-agents", "3", "--n-paths", "1", "--out", "u"],
        cwd=tmp,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    done = subprocess.run([*cli, "evaluate", "--out", "e"], cwd=tmp, capture_output=True, text=True)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 1 and len(lines) == 1, done.stderr
    assert 'pip install "agent-envs[train]"' in lines[0], lines
print(f"minimal install OK: agent_envs {agent_envs.__version__}, episode cost {-total:.4f}")

# The benchmark on the core install: the task list and scoring a callable policy (numpy only;
# the references are package data, checked against their recorded hash).
with tempfile.TemporaryDirectory() as tmp:
    with open(f"{tmp}/third_party.py", "w") as handle:
        handle.write(
            "import numpy as np\n"
            "def act(obs):\n"
            "    return np.clip(12.0 * (obs[20] - obs[:10]) / 25.0, -1, 1)\n"
        )
    done = subprocess.run([*cli, "tasks"], cwd=tmp, capture_output=True, text=True)
    assert done.returncode == 0 and "agent_envs/StiffSwarm-v0" in done.stdout, done.stderr
    done = subprocess.run(
        [
            *cli,
            "evaluate",
            "--task",
            "agent_envs/NoisySwarm-v0",
            "-p",
            "third_party:act",
            "-p",
            "proportional",
            "--out",
            "s",
        ],
        cwd=tmp,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    with open(f"{tmp}/s/scores.csv") as handle:
        assert sum(1 for line in handle if ",act,policy," in line) == 20
from agent_envs.tasks import score  # noqa: E402

result = score(lambda obs: np.zeros(10, np.float32), "agent_envs/NoisySwarm-v0")
assert abs(result.summary()["score"].mean) < 1e-9, result
bad = sorted(m for m in ("torch", "stable_baselines3", "pandas") if m in sys.modules)
assert not bad, bad
print("minimal install: tasks listed and a callable scored without torch")
