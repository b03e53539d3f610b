"""The results: per-episode records and tables, their statistics, reports and plots.

`rollout` runs one episode of a policy and records it (`tables.Episode`); `tables` holds the
per-policy episode tables (`EvaluationResults`) and their summaries; `seed_statistics` the
across-seed statistics (IQM, bootstrap intervals, probability of improvement); `report` the
Markdown + HTML reports with PNG plots; `committed_tables` and `command_tables` the published
tables of the committed outputs, and `episode_csv`, `env_options_episodes`, `max_control_seeds`
and `apg_episodes` the benchmark scripts' per-episode files those tables are recomputed from.
Results import only the training layer's infrastructure
(`config`, `defaults`, `storage`): never a learner, never a command.
"""
