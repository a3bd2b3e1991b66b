"""Controllers: turn an action in a control mode into PD joint targets."""
