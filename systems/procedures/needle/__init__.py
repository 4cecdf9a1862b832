"""The generic needle procedure (thesis ch. 3): steps, scoring, feedback and the C-arm, all read from pack data."""
