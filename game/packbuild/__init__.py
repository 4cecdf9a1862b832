"""Jobs that build the shipped packs from source data: the prp anatomy, its scripted attempts, the cutting pack."""
