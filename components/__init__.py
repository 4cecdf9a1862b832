"""Plain-data components. Every module here registers its types with chainsim.components.registry on import."""
