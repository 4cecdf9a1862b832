"""Plain-data components. Every module here registers its types with game.registry on import."""
