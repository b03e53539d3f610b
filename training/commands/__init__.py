"""The commands of `agent-envs`: what a user runs, built on the learners and the results.

`cli` (the argparse of every subcommand), `train`, `evaluate` (+ `evaluate_options`),
`compare`, `sweep` (+ `sweep_report`), `tune`, `leaderboard`, the benchmark's tasks
(`task_evaluation`, `task_references`) and what several commands share: `presets` (the one
registry of experiment settings) and `experiment` (the experiment builder). Commands import the
learners, the results and the infrastructure; nothing below imports a command.
"""
