"""Tasks and scenarios: what an episode must achieve, and how its start is drawn.

* :mod:`.registry`: the sub-skill tasks (:data:`TASKS`: id -> :class:`TaskSpec` with its success
  predicate, reset distribution, episode length and expert), the chained scenarios
  (:data:`SCENARIOS`), the reset distribution (:class:`ResetDistribution`, what the env samples)
  and the per-episode metric :func:`mean_squared_jerk`;
* :mod:`.clear_desk`: the ``clear_desk`` scenario (five objects in one cell, cleared one after
  another by the scripted expert).
"""

from flatlab_lerobot.tasks.registry import (
    DEFAULT_PLANAR,
    DEFAULT_YAW_DEG,
    SCENARIOS,
    TASKS,
    ResetDistribution,
    Scenario,
    TaskContext,
    TaskSpec,
    get_task,
    mean_squared_jerk,
    run_scenario,
    task_context,
    touches,
)

__all__ = [
    "DEFAULT_PLANAR", "DEFAULT_YAW_DEG", "SCENARIOS", "TASKS", "ResetDistribution", "Scenario", "TaskContext",
    "TaskSpec", "get_task", "mean_squared_jerk", "run_scenario", "task_context", "touches",
]  # fmt: skip
