"""Trainee records: the store, its schema and migrations, validation of what goes in, and reports."""
