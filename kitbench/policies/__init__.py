"""Policies kitbench can run: the expert planners, baselines, dataset replay and LeRobot checkpoints."""
