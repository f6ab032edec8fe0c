"""What a timeline plot drew, read back from its PNG: which of the expected colours appear."""

from __future__ import annotations

from pathlib import Path

import matplotlib.colors
import matplotlib.image
import numpy as np


def colours_drawn(path: Path, colours: list[str], min_pixels: int = 20) -> set[str]:
    """The colours (hex) of `colours` that fill at least `min_pixels` pixels of the PNG exactly."""
    image = matplotlib.image.imread(path)[..., :3]
    pixels = np.round(image.reshape(-1, 3) * 255).astype(np.int64)
    codes = pixels[:, 0] * 65536 + pixels[:, 1] * 256 + pixels[:, 2]
    found = set()
    for colour in colours:
        r, g, b = (round(c * 255) for c in matplotlib.colors.to_rgb(colour))
        if int(np.sum(codes == r * 65536 + g * 256 + b)) >= min_pixels:
            found.add(colour)
    return found
