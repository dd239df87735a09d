"""Writes environment.png, the lat-long image of dome_texture.usda (8-bit sRGB, 128 x 64): run once, the PNG is
committed beside it. A sky over a brown ground, with four coloured markers on the horizon where OpenEXR's lat-long
convention puts the axes: red at +X (u = 0.25), green at +Z (u = 0.5), blue at -X (u = 0.75), white at -Z (the seam)."""

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent / "testTextures"))
from make_textures import write_png  # noqa: E402


def main() -> None:
    width, height = 128, 64
    rows, columns = np.mgrid[0:height, 0:width] + 0.5
    v, u = rows / height, columns / width  # v from the top row
    latitude = (0.5 - v) * np.pi
    sky = np.stack([0.35 + 0.3 * (1 - np.sin(latitude)), 0.55 + 0.25 * (1 - np.sin(latitude)), np.full_like(u, 0.95)], -1)
    ground = np.broadcast_to(np.array([0.35, 0.25, 0.15]), sky.shape)
    image = np.where((latitude > 0)[..., None], sky, ground)
    near_horizon = np.abs(latitude) < np.radians(25)
    for centre, color in ((0.25, (1, 0, 0)), (0.5, (0, 1, 0)), (0.75, (0, 0, 1)), (0.0, (1, 1, 1))):
        distance = np.abs((u - centre + 0.5) % 1.0 - 0.5)
        image[near_horizon & (distance < 0.06)] = color
    write_png(HERE / "environment.png", np.round(image * 255).astype(np.uint8))


if __name__ == "__main__":
    main()
