"""CI: with only `pip install agent-envs` (no extras), the core works and imports no torch.

Run from outside the repository so that the installed wheel, not the source tree, is imported.
"""

import subprocess
import sys
import tempfile

import gymnasium as gym

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
cli = [sys.executable, "-m", "agent_envs.training.cli"]
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
