"""The ChainMail demos' procedure: a marked element, a reset and the step text (thesis 5.3)."""
