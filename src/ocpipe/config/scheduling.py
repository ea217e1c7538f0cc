"""Which jobs Snakemake starts first when more are ready than cores are free (a rule's `priority:`).

On 2 cores a long chain that starts last runs alone at the end while a core idles, so the long chains start first
(longest processing time first, which keeps a greedy schedule's makespan near the shortest). The record of a whole
study on 2 cores (docs/results/compute.md) gives the chains' lengths:
- a second task's chain (StackCube) begins with stores of its own (demos, frames, features and read-out scenes: about
  27 core-minutes before its first policy trains) and its policies run the longest episodes (cap 200 against 150);
- a policy's training grows with its window T (T = 40 trained for 13.3 core-minutes, T = 5 for 3.6).
The privileged-state control is a short chain (2.2 core-minutes a policy) and keeps the default.

A store job (demos, frames, features, scenes, the encoder's training) gates every policy that reads its task's
stores, so it goes before any policy job.

Snakemake starts the ready jobs whose priorities sum highest among those that fit the free cores (its MILP
scheduler), so two one-thread jobs outrank one two-thread job of the same priority, and a two-thread job can wait
for as long as one-thread jobs keep coming: in a run of the main job the dual-camera features job, which gates all
15 visual policies, waited 17 minutes (16:35:45-16:52:54) behind the control's policies and the read-out scenes.
A job of t > 1 threads therefore also gets more than t times the highest priority of a one-thread job: whenever its
cores are free together, it starts before any t one-thread jobs. It can still wait while a one-thread job holds a
core (Snakemake keeps no core free for it), so the default profile gives feature extraction one thread."""

from __future__ import annotations

LONGEST = 2  # a task other than the base policy's: its stores and every policy that reads them
LONGER = 1  # a policy whose window is longer than the base policy's
STORES = LONGEST + 1  # every store job, above every policy job
NARROW_MOST = STORES + LONGEST  # the highest priority of a one-thread job


def _wide(priority: int, threads: int) -> int:
    return priority + (threads * NARROW_MOST + 1 if threads > 1 else 0)


def task_priority(task: str, config: dict, threads: int = 1) -> int:
    """The priority of a store job (demos, frames, features, scenes, encoder training) of ``task``."""
    return _wide(STORES + (LONGEST if task != config["policy"]["task"] else 0), threads)


def policy_priority(policy: dict, config: dict, threads: int = 1) -> int:
    """The priority of a training or evaluation job of a policy with resolved settings ``policy``."""
    if policy["task"] != config["policy"]["task"]:
        return _wide(LONGEST, threads)
    return _wide(LONGER if policy["window"] > config["policy"]["window"] else 0, threads)
