"""The benchmark: versioned swarm tasks, their shipped references, and the score.

    import agent_envs
    from agent_envs import tasks
    tasks.TASKS                                    # id -> TaskSpec
    result = tasks.score(my_policy, "agent_envs/StiffSwarm-v0")   # numpy only, no re-solve
    result.summary()                               # mean score, IQM, CIs, per-seed rows

A task (`catalog`) fixes the dynamics, cost, horizon, numerics, test seeds and reference data
of one problem under a versioned Gymnasium id; `envs` registers it (single env, native vector
env) and builds its PettingZoo twin; `references` reads the shipped per-seed costs of its
references after checking their recorded hash; `scores` holds the score's arithmetic and its
aggregation over seeds; `scoring` runs a policy on the test seeds and scores it; `bounds` is
the certified lower bound used where no optimum can be solved.
"""

from agent_envs.tasks.catalog import (
    INTERFACE_KWARGS,
    TASK_LIST,
    TASKS,
    TaskSpec,
    get_task,
)
from agent_envs.tasks.envs import make_task_env, make_task_vector_env, parallel_env, register_tasks
from agent_envs.tasks.references import TaskReferences, load_references
from agent_envs.tasks.scores import gap, normalized_score, summarize
from agent_envs.tasks.scoring import PolicyError, TaskScore, score

__all__ = [
    "INTERFACE_KWARGS",
    "TASKS",
    "TASK_LIST",
    "PolicyError",
    "TaskReferences",
    "TaskScore",
    "TaskSpec",
    "gap",
    "get_task",
    "load_references",
    "make_task_env",
    "make_task_vector_env",
    "normalized_score",
    "parallel_env",
    "register_tasks",
    "score",
    "summarize",
]
