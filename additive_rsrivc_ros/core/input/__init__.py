"""What the data are before the estimator sees them: stamps, values, gaps, stuck sensors, stream alignment."""
