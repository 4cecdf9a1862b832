"""The App and how a run is built: the ECS loop and its stages, plugins, spawning a pack, headless runs, digests."""
