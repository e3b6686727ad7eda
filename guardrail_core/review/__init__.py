"""Learning from the operators' labels: training on a run's reviewed segments."""
