"""What every part of the shell shares: output paths (outputs), logging (logs) and the user's options."""
