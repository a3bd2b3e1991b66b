"""What every task shares: the tabletop env base with the task hooks (`tabletop`), modes, observation
assembly, the grasp history failure categories read, and the LeRobot feature spec. The tasks themselves are in
`kitbench.tasks`."""
