"""Recording demonstrations: LeRobot v3 datasets and per-episode MCAP logs."""
