"""Built-in asset packs: each sub-folder with a pack.toml is one procedure or demo."""
