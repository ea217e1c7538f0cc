"""Which jobs Snakemake starts first when more are ready than cores are free (a rule's `priority:`).

On 2 cores a long chain that starts last runs alone at the end while a core idles, so the long chains start first
(longest processing time first, which keeps a greedy schedule's makespan near the shortest). The record of a whole
study on 2 cores (docs/results/compute.md) gives the chains' lengths:
- a second task's chain (StackCube) begins with stores of its own (demos, frames, features and read-out scenes: about
  27 core-minutes before its first policy trains) and its policies run the longest episodes (cap 200 against 150);
- a policy's training grows with its window T (T = 40 trained for 13.3 core-minutes, T = 5 for 3.6).
The privileged-state control is a short chain (2.2 core-minutes a policy) and keeps the default."""

from __future__ import annotations

LONGEST = 2  # a task other than the base policy's: its stores and every policy that reads them
LONGER = 1  # a policy whose window is longer than the base policy's


def task_priority(task: str, config: dict) -> int:
    """The priority of a store job (demos, frames, features, scenes) of ``task``."""
    return LONGEST if task != config["policy"]["task"] else 0


def policy_priority(policy: dict, config: dict) -> int:
    """The priority of a training or evaluation job of a policy with resolved settings ``policy``."""
    if policy["task"] != config["policy"]["task"]:
        return LONGEST
    return LONGER if policy["window"] > config["policy"]["window"] else 0
