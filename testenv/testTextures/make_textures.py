"""Writes the textures of textures.usda (8-bit PNGs, zlib only): run once, the PNGs are committed beside it."""

import struct
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent


def write_png(path: Path, pixels: np.ndarray) -> None:
    """Rows top first; 1 (grey), 3 (RGB) or 4 (RGBA) channels of 8 bits."""
    pixels = np.asarray(pixels, np.uint8)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    height, width, channels = pixels.shape
    color_type = {1: 0, 3: 2, 4: 6}[channels]
    raw = b"".join(b"\0" + pixels[y].tobytes() for y in range(height))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, color_type, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def main() -> None:
    y, x = np.mgrid[0:64, 0:64]
    # A checker of 8 x 8 cells, white and dark blue (sRGB).
    cells = ((x // 8 + y // 8) % 2 == 0)[..., None]
    write_png(HERE / "checker.png", np.where(cells, [235, 235, 235], [30, 50, 120]))
    # Orientation: red grows with s, green with t (rows are top first: t grows upwards), a blue block at st (0, 0).
    y16, x16 = np.mgrid[0:16, 0:16]
    ramp = np.stack([x16 * 17, (15 - y16) * 17, np.zeros_like(x16)], axis=-1)
    ramp[12:16, 0:4] = [40, 80, 255]
    write_png(HERE / "orientation.png", ramp)
    # Orange with a round hole (alpha 0 inside radius 20 texels of the centre).
    hole = (x - 31.5) ** 2 + (y - 31.5) ** 2 < 20 ** 2
    write_png(HERE / "hole.png", np.dstack([np.full((64, 64), 240), np.full((64, 64), 140), np.full((64, 64), 40), np.where(hole, 0, 255)]))
    # A tangent-space normal map of 4 x 4 domes (raw): the slope of a sphere cap of radius 7 texels in each 16-texel
    # cell; and a roughness ramp, 0.1 at s = 0 to 0.9 at s = 1 (one channel).
    u, v = (x + 0.5) / 64.0, 1.0 - (y + 0.5) / 64.0
    du, dv = (x % 16) - 7.5, 7.5 - (y % 16)  # texels from the cell centre, v up
    inside = du * du + dv * dv < 7.0 ** 2
    cap = np.sqrt(np.maximum(7.0 ** 2 - du * du - dv * dv, 1.0))
    n = np.stack([np.where(inside, du, 0.0), np.where(inside, dv, 0.0), np.where(inside, cap, 1.0)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    write_png(HERE / "bumps_normal.png", np.round((n * 0.5 + 0.5) * 255))
    write_png(HERE / "roughness.png", np.round((0.1 + 0.8 * u) * 255))


if __name__ == "__main__":
    main()
