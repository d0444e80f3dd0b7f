"""Gymnasium registration of every ciflow task (single and vector entry points)."""

import gymnasium

from ciflow import _native

#: Gymnasium ids of every task, as the engine built into this package lists them.
TASK_IDS = tuple(task_id for task_id, _name in _native.tasks())


def register_tasks() -> None:
    """Registers each task id; idempotent. Time limits come from the engine (the task
    sets ``truncated``), so no ``TimeLimit`` wrapper is added."""
    for task_id in TASK_IDS:
        if task_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=task_id,
            entry_point="ciflow.env:CiflowEnv",
            vector_entry_point="ciflow.vector:CiflowVectorEnv",
            kwargs={"task": task_id},
            disable_env_checker=False,
        )


def task_entry(task: str) -> tuple[str, str]:
    """``(gymnasium id, command-line name)`` of ``task`` given by either."""
    for task_id, name in _native.tasks():
        if task in (task_id, name):
            return task_id, name
    known = ", ".join(name for _, name in _native.tasks())
    raise ValueError(f"unknown task {task!r}; known: {known}")
