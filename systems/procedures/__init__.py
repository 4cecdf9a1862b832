"""Procedure systems: one folder per procedure the app can run (its steps, scoring and feedback)."""
