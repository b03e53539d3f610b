"""PPO on an agent_envs benchmark task in one file, in the shape of CleanRL's ppo_continuous_action.

Only gymnasium, numpy and torch, plus ``import agent_envs`` to register the task ids. It trains
on the task's native vector env, normalizes observations itself (running mean and variance,
saved with the policy), and saves the deterministic actor and those statistics as a plain
``.npz`` (no pickle). `policy(env)` loads that file again with numpy alone, so scoring needs no
torch. Run both commands from the repository root:

    python examples/cleanrl_ppo_swarm.py --task agent_envs/NoisySwarm-v0 --total-timesteps 50000
    agent-envs evaluate --task agent_envs/NoisySwarm-v0 \\
        -p cleanrl=examples.cleanrl_ppo_swarm:policy --out scores-cleanrl

The second command scores the policy on the task's 20 test seeds. It loads the file named by
the environment variable CLEANRL_SWARM_POLICY, or runs/cleanrl_ppo_swarm.npz if that is unset.
"""

import argparse
import os
import shlex
import time
from dataclasses import dataclass, fields
from pathlib import Path

import gymnasium as gym
import numpy as np

import agent_envs  # noqa: F401  (registers the agent_envs/... task ids)

DEFAULT_SAVE_PATH = "runs/cleanrl_ppo_swarm.npz"
POLICY_ENV_VAR = "CLEANRL_SWARM_POLICY"
OBS_CLIP = 10.0  # normalized observations are clipped to [-OBS_CLIP, OBS_CLIP]
OBS_EPS = 1e-8
SQRT2 = float(np.sqrt(2))  # CleanRL's orthogonal init gain of the hidden layers


@dataclass
class Args:
    task: str = "agent_envs/NoisySwarm-v0"  # the task id (agent-envs tasks lists them)
    seed: int = 1  # seeds torch, the minibatch generator and the envs' first reset
    total_timesteps: int = 50_000  # env steps, summed over the vector env's copies
    learning_rate: float = 3e-4
    num_envs: int = 8  # copies in the native vector env
    num_steps: int = 128  # steps per copy per rollout
    anneal_lr: bool = True
    gamma: float = 0.99
    gae_lambda: float = 0.95
    num_minibatches: int = 32
    update_epochs: int = 10
    norm_adv: bool = True
    clip_coef: float = 0.2
    clip_vloss: bool = True
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float = 0.0  # stop an update's epochs once the approximate KL passes it (0: off)
    init_logstd: float = -1.5  # std 0.22: exploring with std 1 costs ~6x the zero control
    hidden: int = 64  # width of the two tanh layers of actor and critic
    torch_threads: int = 1  # the networks are tiny: more threads only add overhead
    save_path: str = DEFAULT_SAVE_PATH  # where the policy (.npz) is written


def parse_args(argv: list[str] | None = None) -> Args:
    """Args from the command line: one --flag-name per field of `Args`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for f in fields(Args):
        flag = "--" + f.name.replace("_", "-")
        if f.type is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default)
        else:
            parser.add_argument(flag, type=f.type, default=f.default, help="(default: %(default)s)")
    return Args(**vars(parser.parse_args(argv)))


# ----------------------------------------------------------------- numpy: statistics and policy
class RunningMeanStd:
    """Running mean and variance of observations (parallel update, as gymnasium's wrapper)."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.mean = np.zeros(shape, np.float64)
        self.var = np.ones(shape, np.float64)
        self.count = 1e-4

    def update(self, batch: np.ndarray) -> None:
        b_mean, b_var, b_count = batch.mean(axis=0), batch.var(axis=0), batch.shape[0]
        delta, total = b_mean - self.mean, self.count + b_count
        m2 = self.var * self.count + b_var * b_count + delta**2 * self.count * b_count / total
        self.mean, self.var, self.count = self.mean + delta * b_count / total, m2 / total, total


def normalize(obs: np.ndarray, mean: np.ndarray, var: np.ndarray) -> np.ndarray:
    return np.clip((obs - mean) / np.sqrt(var + OBS_EPS), -OBS_CLIP, OBS_CLIP)


def save_policy(path, layers, obs_mean, obs_var, *, task: str = "", logstd=None) -> Path:
    """Write the actor's layers [(W (in, out), b), ...] and the observation statistics as .npz.

    numpy only, no pickled objects: `load_policy` reads it with ``allow_pickle=False``.
    """
    arrays = {"obs_mean": np.asarray(obs_mean, np.float64), "obs_var": np.asarray(obs_var)}
    for k, (w, b) in enumerate(layers):
        arrays[f"w{k}"] = np.asarray(w, np.float32)
        arrays[f"b{k}"] = np.asarray(b, np.float32)
    arrays["n_layers"] = np.array(len(layers))
    arrays["task"] = np.array(task)
    if logstd is not None:
        arrays["logstd"] = np.asarray(logstd, np.float32)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:  # a file object: np.savez would append .npz to a bare name
        np.savez(fh, **arrays)
    return path


class NumpyPolicy:
    """obs -> action: normalize, tanh MLP (the actor mean), clip to [-1, 1], float32."""

    def __init__(self, path) -> None:
        with np.load(path, allow_pickle=False) as data:
            n = int(data["n_layers"])
            self.layers = [(data[f"w{k}"], data[f"b{k}"]) for k in range(n)]
            self.obs_mean, self.obs_var = data["obs_mean"], data["obs_var"]
            self.task = str(data["task"])
        self.obs_dim, self.act_dim = self.layers[0][0].shape[0], self.layers[-1][0].shape[1]

    def __call__(self, obs) -> np.ndarray:
        x = normalize(np.asarray(obs, np.float64), self.obs_mean, self.obs_var).astype(np.float32)
        for k, (w, b) in enumerate(self.layers):
            x = x @ w + b
            if k < len(self.layers) - 1:
                x = np.tanh(x)
        return np.clip(x, -1.0, 1.0).astype(np.float32)


def policy(env):
    """Factory for ``agent-envs evaluate -p NAME=examples.cleanrl_ppo_swarm:policy``.

    Loads $CLEANRL_SWARM_POLICY (default runs/cleanrl_ppo_swarm.npz) and checks it fits `env`.
    """
    path = os.environ.get(POLICY_ENV_VAR, DEFAULT_SAVE_PATH)
    if not Path(path).is_file():
        raise FileNotFoundError(f"no saved policy at {path}: train first, or set {POLICY_ENV_VAR}")
    loaded = NumpyPolicy(path)
    obs_dim = int(np.prod(env.observation_space.shape))
    act_dim = int(np.prod(env.action_space.shape))
    if (loaded.obs_dim, loaded.act_dim) != (obs_dim, act_dim):
        raise ValueError(
            f"{path} (trained on {loaded.task or 'an unnamed task'}) maps {loaded.obs_dim} "
            f"observations to {loaded.act_dim} actions; this env has {obs_dim} and {act_dim}"
        )
    return loaded


# ------------------------------------------------------------------------- torch: the learner
def build_agent(obs_dim: int, act_dim: int, hidden: int, init_logstd: float):
    """CleanRL's Agent (torch is imported here, so that scoring a saved policy needs none)."""
    import torch
    from torch import nn
    from torch.distributions.normal import Normal

    def layer_init(layer, std=SQRT2, bias_const=0.0):
        nn.init.orthogonal_(layer.weight, std)
        nn.init.constant_(layer.bias, bias_const)
        return layer

    def mlp(out_dim: int, out_std: float) -> nn.Sequential:
        return nn.Sequential(
            layer_init(nn.Linear(obs_dim, hidden)),
            nn.Tanh(),
            layer_init(nn.Linear(hidden, hidden)),
            nn.Tanh(),
            layer_init(nn.Linear(hidden, out_dim), std=out_std),
        )

    class Agent(nn.Module):
        def __init__(self):
            super().__init__()
            self.critic = mlp(1, 1.0)
            self.actor_mean = mlp(act_dim, 0.01)
            self.actor_logstd = nn.Parameter(torch.full((1, act_dim), float(init_logstd)))

        def get_value(self, x):
            return self.critic(x)

        def get_action_and_value(self, x, action=None):
            action_mean = self.actor_mean(x)
            action_std = torch.exp(self.actor_logstd.expand_as(action_mean))
            probs = Normal(action_mean, action_std)
            if action is None:
                action = probs.sample()
            return action, probs.log_prob(action).sum(1), probs.entropy().sum(1), self.critic(x)

        def actor_layers(self):
            """[(W (in, out), b), ...] of the actor mean, as numpy arrays for `save_policy`."""
            linears = [m for m in self.actor_mean if isinstance(m, nn.Linear)]
            return [(m.weight.detach().numpy().T, m.bias.detach().numpy()) for m in linears]

    return Agent()


def train(args: Args) -> Path:
    import torch
    from torch import optim

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.torch_threads)
    rng = np.random.default_rng(args.seed)  # minibatch order; never the global numpy RNG
    batch_size = args.num_envs * args.num_steps
    num_iterations = max(1, args.total_timesteps // batch_size)

    envs = gym.make_vec(args.task, num_envs=args.num_envs, vectorization_mode="vector_entry_point")
    assert isinstance(envs.single_action_space, gym.spaces.Box), "continuous actions only"
    obs_dim = int(np.prod(envs.single_observation_space.shape))
    act_dim = int(np.prod(envs.single_action_space.shape))
    agent = build_agent(obs_dim, act_dim, args.hidden, args.init_logstd)
    optimizer = optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)
    obs_rms = RunningMeanStd((obs_dim,))

    shape = (args.num_steps, args.num_envs)
    obs = torch.zeros((*shape, obs_dim))
    actions = torch.zeros((*shape, act_dim))
    logprobs, rewards, dones, values = (torch.zeros(shape) for _ in range(4))
    # The native vector env resets in NEXT_STEP mode: the step after an episode's last one only
    # resets (its action is ignored, reward 0). Those steps are kept out of the PPO loss.
    valid = np.zeros(shape, bool)

    global_step, start_time, costs = 0, time.time(), []
    next_obs_raw, _ = envs.reset(seed=args.seed)
    next_valid = np.ones(args.num_envs, bool)
    episode_cost = np.zeros(args.num_envs)
    for iteration in range(1, num_iterations + 1):
        if args.anneal_lr:
            frac = 1.0 - (iteration - 1.0) / num_iterations
            optimizer.param_groups[0]["lr"] = frac * args.learning_rate

        for step in range(args.num_steps):
            global_step += args.num_envs
            obs_rms.update(next_obs_raw)
            next_obs = torch.as_tensor(normalize(next_obs_raw, obs_rms.mean, obs_rms.var)).float()
            obs[step], valid[step] = next_obs, next_valid
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(next_obs)
            actions[step], logprobs[step], values[step] = action, logprob, value.flatten()

            env_action = np.clip(action.numpy(), -1.0, 1.0)
            next_obs_raw, reward, terminations, truncations, _ = envs.step(env_action)
            done = np.logical_or(terminations, truncations)
            rewards[step] = torch.as_tensor(reward).float()
            dones[step] = torch.as_tensor(done).float()
            episode_cost -= reward
            costs.extend(episode_cost[done].tolist())
            episode_cost[done] = 0.0
            next_valid = ~done

        # GAE. An episode's end is final (fixed horizon, t/T observed): no bootstrap after it.
        with torch.no_grad():
            last_obs = normalize(next_obs_raw, obs_rms.mean, obs_rms.var)
            next_value = agent.get_value(torch.as_tensor(last_obs).float()).flatten()
            advantages = torch.zeros_like(rewards)
            lastgaelam = 0
            for t in reversed(range(args.num_steps)):
                nextvalues = next_value if t == args.num_steps - 1 else values[t + 1]
                nextnonterminal = 1.0 - dones[t]
                delta = rewards[t] + args.gamma * nextvalues * nextnonterminal - values[t]
                lastgaelam = delta + args.gamma * args.gae_lambda * nextnonterminal * lastgaelam
                advantages[t] = lastgaelam
            returns = advantages + values

        b_obs, b_actions = obs.reshape(-1, obs_dim), actions.reshape(-1, act_dim)
        b_logprobs, b_advantages = logprobs.reshape(-1), advantages.reshape(-1)
        b_returns, b_values = returns.reshape(-1), values.reshape(-1)
        b_inds = np.flatnonzero(valid.reshape(-1))

        clipfracs = []
        for _epoch in range(args.update_epochs):
            for mb_inds in np.array_split(rng.permutation(b_inds), args.num_minibatches):
                if mb_inds.size < 2:  # a tiny batch: nothing to normalize advantages over
                    continue
                mb = torch.as_tensor(mb_inds)
                _, newlogprob, entropy, newvalue = agent.get_action_and_value(
                    b_obs[mb], b_actions[mb]
                )
                logratio = newlogprob - b_logprobs[mb]
                ratio = logratio.exp()
                with torch.no_grad():
                    approx_kl = ((ratio - 1) - logratio).mean()
                    clipfracs.append(((ratio - 1.0).abs() > args.clip_coef).float().mean().item())

                mb_advantages = b_advantages[mb]
                if args.norm_adv:
                    mb_advantages = (mb_advantages - mb_advantages.mean()) / (
                        mb_advantages.std() + 1e-8
                    )
                pg_loss1 = -mb_advantages * ratio
                pg_loss2 = -mb_advantages * torch.clamp(
                    ratio, 1 - args.clip_coef, 1 + args.clip_coef
                )
                pg_loss = torch.max(pg_loss1, pg_loss2).mean()

                newvalue = newvalue.view(-1)
                v_loss_unclipped = (newvalue - b_returns[mb]) ** 2
                if args.clip_vloss:
                    v_clipped = b_values[mb] + torch.clamp(
                        newvalue - b_values[mb], -args.clip_coef, args.clip_coef
                    )
                    v_loss_clipped = (v_clipped - b_returns[mb]) ** 2
                    v_loss = 0.5 * torch.max(v_loss_unclipped, v_loss_clipped).mean()
                else:
                    v_loss = 0.5 * v_loss_unclipped.mean()

                loss = pg_loss - args.ent_coef * entropy.mean() + v_loss * args.vf_coef
                optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
            if args.target_kl > 0 and approx_kl > args.target_kl:
                break

        if iteration % max(1, num_iterations // 10) == 0 or iteration == num_iterations:
            recent = f"{np.mean(costs[-50:]):.4f}" if costs else "n/a"
            print(
                f"step {global_step:>7}  episode cost (last {min(len(costs), 50)}) {recent}  "
                f"v_loss {v_loss.item():.2e}  clipfrac {np.mean(clipfracs):.3f}  "
                f"SPS {int(global_step / (time.time() - start_time))}"
            )
    envs.close()
    layers, logstd = agent.actor_layers(), agent.actor_logstd.detach().numpy().ravel()
    return save_policy(
        args.save_path, layers, obs_rms.mean, obs_rms.var, task=args.task, logstd=logstd
    )


if __name__ == "__main__":
    args = parse_args()
    saved = train(args)
    print(f"saved the policy to {saved}\nscore it on the task's test seeds (from the repo root):")
    prefix = ""
    if Path(args.save_path).resolve() != Path(DEFAULT_SAVE_PATH).resolve():
        prefix = f"{POLICY_ENV_VAR}={shlex.quote(str(saved.resolve()))} "
    print(
        f"  {prefix}agent-envs evaluate --task {args.task} "
        "-p cleanrl=examples.cleanrl_ppo_swarm:policy --out scores-cleanrl"
    )
