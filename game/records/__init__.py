"""Trainee records: the store and all its SQL, accounts, the schema and its migrations, validation of what goes in,
exports (CSV, xAPI), reports, and saving to a records server with an offline queue (remote)."""
