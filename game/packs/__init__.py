"""Asset packs: discovery, manifest schema and validation, the loaded `Pack`, and the new-pack scaffold."""
