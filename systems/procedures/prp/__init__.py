"""The percutaneous rhizotomy trainer (thesis ch. 3): steps, needle scoring and the assessment tool."""
