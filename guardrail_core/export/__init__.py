"""A run's results out to other tools' formats."""
