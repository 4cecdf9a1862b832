"""Built-in asset packs: each sub-folder with a pack.toml is one procedure or demo; `presets/` holds material presets.

Data only: this package holds no code besides the location below.
"""

from pathlib import Path

ASSETS_DIR = Path(__file__).resolve().parent
