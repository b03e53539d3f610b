"""The paper's experiments, reproduced (Cassini & Segala, arXiv 2503.09549, Section 5).

- `uncontrolled`: Section 5.1 (Figs. 1-4): the uncontrolled swarm under EM, EE, Heun, ERB and
  SERB, with a Jacobian study.
- `turnpike_controlled`: Section 5.2 (Figs. 5-6): the turnpike-controlled swarm, through the
  Gymnasium env and as the paper's closed loop.

Each module has ``reproduce(out_dir, ...)`` (writes tables and figures); the command line is
`agent-envs reproduce uncontrolled|turnpike` (`agent_envs.training.cli`).
"""
