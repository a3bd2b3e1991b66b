"""`kitbench eval`: score a policy on a fixed seed list with the task's own success criteria and write a report."""
