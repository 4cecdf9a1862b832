"""The cutting trainer (thesis 4.5): instruments on layered tissue."""
