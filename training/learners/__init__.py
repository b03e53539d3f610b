"""The learners: how a policy is trained and loaded.

Stable-Baselines3's algorithms (their envs: the Gymnasium env, the native `VecEnv`, the
PettingZoo env through SuperSuit; evaluation callbacks; checkpoints) and `apg`, the analytic
policy gradient through the core's integrator (its feedback law and differentiable rollout);
`policies` loads any of them as an SB3 `PolicyPredictor`. Learners import the results room and
the training layer's infrastructure (`config`, `defaults`, `storage`), never the commands.
"""
