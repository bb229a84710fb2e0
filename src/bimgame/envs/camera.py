"""The camera part of domain randomisation (:mod:`bimgame.envs.randomization`): each env's camera
moved, rotated, defocused, with its own contrast, brightness and noise, applied to batches of the
raster's uint8 frames with numpy.

Every effect but the noise is linear in the frame, and a frame is the static background plus its
marbles' discs (:mod:`bimgame.sim.render`). So each env's view of the background is computed once
per episode, and per step only a window around each marble is transformed (its difference from the
background) and added. Work arrays are kept between calls: on the reference machine a fresh
megabyte-sized numpy temporary costs more in page faults than the arithmetic done in it.
"""

from __future__ import annotations

import math

import numpy as np

from bimgame.sim.render import MazeRenderer

__all__ = ["CameraView", "MID_GRAY"]

MID_GRAY = 127.5  #: the gray level contrast scales about


class CameraView:
    """The camera effects of ``batch`` envs, each with its own episode's parameters (:meth:`set_row`),
    on batches of ``raster``'s frames (:meth:`apply`), computed as the module docstring says.

    Sampling is bilinear, the camera moved by its offset and rotated counter-clockwise about the
    image centre (the board's centre); beyond the image the edge pixels repeat (beyond the rim the
    board is uniformly wall-coloured). The blur is a separable Gaussian; for the background the
    border repeats, for the marbles' part it is zero, which differs only for a marble within the
    blur radius of the border.
    """

    def __init__(self, raster: MazeRenderer, batch: int, blur_radius: int):
        self.size = raster.size
        self.batch = batch
        self.radius = blur_radius
        self.background = raster.background.reshape(-1).astype(np.float32)
        self.cos, self.sin = np.ones((batch, 1)), np.zeros((batch, 1))
        self.shift = np.zeros((batch, 2))  # x (right), y (down), px
        self.taps = np.zeros((batch, blur_radius + 1), dtype=np.float32)  # centre tap first
        self.gain = np.ones((batch, 1), dtype=np.float32)
        self.noise_std = np.zeros((batch, 1), dtype=np.float32)
        self.base = np.zeros((batch, self.size * self.size), dtype=np.float32)  # the background's view
        # A marble changes pixels within radius + 0.5 px of its centre, bilinear sampling reaches a
        # pixel farther (√2 diagonally); +1 for rounding the window's centre (≤ √2/2). The blur
        # spreads that window by its radius (the window a marble changes in the end: ``half``).
        self.half_sampled = math.ceil(raster.marble_radius_px + 0.5 + math.sqrt(2)) + 1
        self.half = self.half_sampled + blur_radius
        rows, cols = np.mgrid[-self.half : self.half + 1, -self.half : self.half + 1]
        self._window = rows.ravel().astype(np.float64), cols.ravel().astype(np.float64)
        h = self.half_sampled
        rows, cols = np.mgrid[-h : h + 1, -h : h + 1]
        self._sampled = rows.ravel().astype(np.float64), cols.ravel().astype(np.float64)
        # Where each sampled pixel takes its value from, relative to the window's centre's source:
        # the offsets rotated by each env's camera (fixed for an episode).
        self._sampled_source = np.zeros((2, batch, rows.size))  # column, row
        rows, cols = np.mgrid[0 : self.size, 0 : self.size].astype(np.float64)
        self._frame_pixels = rows.reshape(1, -1), cols.reshape(1, -1)  # every pixel of a frame: row, col
        self._frame_offsets = (np.arange(batch) * (self.size * self.size))[:, None]  # each env's first pixel
        self._work: dict[tuple, np.ndarray] = {}

    def set_row(
        self,
        row: int,
        shift_x: float,
        shift_y: float,
        rotation: float,
        blur: float,
        contrast: float,
        brightness: float,
        noise_std: float,
    ) -> None:
        """Env ``row``'s camera: offset (px, right and down), rotation (degrees, counter-clockwise),
        blur sigma (px), contrast, brightness (gray levels), noise std (gray levels)."""
        self.cos[row], self.sin[row] = math.cos(math.radians(rotation)), math.sin(math.radians(rotation))
        self.shift[row] = shift_x, shift_y
        if self.radius:
            self.taps[row] = _gaussian_kernel(blur, self.radius)[self.radius :]
        self.gain[row] = contrast
        self.noise_std[row] = noise_std
        dr, dc = self._sampled
        self._sampled_source[0, row] = self.cos[row] * dc - self.sin[row] * dr
        self._sampled_source[1, row] = self.sin[row] * dc + self.cos[row] * dr
        size = self.size
        src_col, src_row = self._source(*self._frame_pixels, slice(row, row + 1))
        index, weight = self._bilinear("base", src_col, src_row)
        view = (self.background[index] * weight).sum(axis=0)
        if self.radius:
            view = self._blur("base", view.reshape(1, size, size), self.taps[row : row + 1], grow=False)
        self.base[row] = view.reshape(-1) * np.float32(contrast) + np.float32(MID_GRAY * (1 - contrast) + brightness)

    def apply(self, frames: np.ndarray, marbles_px: np.ndarray, noise: np.ndarray | None) -> np.ndarray:
        """The camera's view of ``frames`` (batch, 1, S, S) uint8 C-contiguous, written over them and
        returned: their marbles are at pixel coordinates ``marbles_px`` (batch, n, 2) (col, row;
        NaN: none); ``noise`` (batch, S²) holds standard normals (scaled in place by each env's
        std), or None."""
        batch, n = frames.shape[0], self.size * self.size
        frames = np.ascontiguousarray(frames)
        flat = frames.reshape(batch, n)
        image = self.buffer("image", (batch * n + 1,))  # + a last pixel that off-image writes go to
        pixels = image[:-1].reshape(batch, n)
        if noise is None:
            np.copyto(pixels, self.base)
        else:
            noise *= self.noise_std
            np.add(self.base, noise, out=pixels)
        for m in range(marbles_px.shape[1]):
            self._add_marble(image, flat, marbles_px[:, m])
        np.rint(pixels, out=pixels)
        np.clip(pixels, 0, 255, out=pixels)
        np.copyto(flat, pixels, casting="unsafe")
        return frames

    def buffer(self, name: str, shape: tuple[int, ...], dtype: type = np.float32) -> np.ndarray:
        """A work array kept between calls (see the module docstring)."""
        key = (name, shape, dtype)
        buffer = self._work.get(key)
        if buffer is None:
            buffer = self._work[key] = np.empty(shape, dtype=dtype)
        return buffer

    # ------------------------------------------------------------------ helpers
    def _source(self, rows: np.ndarray, cols: np.ndarray, envs: slice) -> tuple[np.ndarray, np.ndarray]:
        """Source pixel coordinates (column, row) that the camera's pixels ``(rows, cols)`` ((b, m)
        for the envs ``envs``) show: moved by the offset, rotated counter-clockwise about the centre."""
        centre = (self.size - 1) / 2
        c, s = self.cos[envs], self.sin[envs]
        u = cols - centre - self.shift[envs, 0:1]
        v = centre + self.shift[envs, 1:2] - rows  # upwards
        return centre + c * u + s * v, centre + s * u - c * v

    def _bilinear(self, name: str, src_col: np.ndarray, src_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear sampling at source coordinates (b, m) (overwritten), clamped to the image (the
        edge repeats): the 4 source pixels' flat indices and weights, (4, b, m) each (work arrays
        ``name``)."""
        size, shape, buf = self.size, src_col.shape, self.buffer
        floor = buf(name + "floor", shape, np.float64)
        corners = []
        for part, src in (("c", src_col), ("r", src_row)):
            np.clip(src, 0, size - 1, out=src)
            np.floor(src, out=floor)
            low, high = buf(name + part + "0", shape, np.intp), buf(name + part + "1", shape, np.intp)
            np.copyto(low, floor, casting="unsafe")
            fraction = buf(name + part + "f", shape)
            np.subtract(src, floor, out=fraction, casting="same_kind")
            np.add(low, 1, out=high)
            np.minimum(high, size - 1, out=high)
            corners.append((low, high, fraction))
        (c0, c1, fc), (r0, r1, fr) = corners
        index, weight = buf(name + "index", (4,) + shape, np.intp), buf(name + "weight", (4,) + shape)
        for k, (r, c) in enumerate(((r0, c0), (r0, c1), (r1, c0), (r1, c1))):
            np.multiply(r, size, out=index[k])
            index[k] += c
        gr, gc = buf(name + "gr", shape), buf(name + "gc", shape)
        np.subtract(1, fr, out=gr)
        np.subtract(1, fc, out=gc)
        for k, (a, b) in enumerate(((gr, gc), (gr, fc), (fr, gc), (fr, fc))):
            np.multiply(a, b, out=weight[k])
        return index, weight

    def _add_marble(self, image: np.ndarray, frames: np.ndarray, centre: np.ndarray) -> None:
        """Add the camera's view of one marble (its frame minus the background) to ``image`` (flat,
        batch·S² + 1); ``centre``: its source pixel coordinates (batch, 2) (col, row)."""
        size, mid, batch = self.size, (self.size - 1) / 2, frames.shape[0]
        m, sampled = self._window[0].size, self._sampled[0].size
        finite = np.isfinite(centre).all(axis=1)
        col = np.where(finite, centre[:, 0], mid)[:, None]
        row = np.where(finite, centre[:, 1], mid)[:, None]
        # Where the camera shows the marble's centre: the inverse of _source.
        u, v = col - mid, mid - row
        shown_col = np.rint(mid + self.cos * u - self.sin * v + self.shift[:, 0:1])
        shown_row = np.rint(mid - (self.sin * u + self.cos * v) + self.shift[:, 1:2])
        rows, cols = self.buffer("rows", (batch, m), np.float64), self.buffer("cols", (batch, m), np.float64)
        np.add(shown_row, self._window[0], out=rows)
        np.add(shown_col, self._window[1], out=cols)
        src_col, src_row = self._source(shown_row, shown_col, slice(None))  # of the window's centre
        source = self.buffer("source", (2, batch, sampled), np.float64)
        np.add(self._sampled_source, np.stack([src_col, src_row]), out=source)
        index, weight = self._bilinear("window", source[0], source[1])
        where = self.buffer("where", (4, batch, sampled), np.intp)
        np.add(index, self._frame_offsets, out=where)
        seen = self.buffer("seen", (4, batch, sampled), np.uint8)
        np.take(frames.reshape(-1), where, out=seen, mode="clip")  # indices are valid: "clip" skips a copy
        difference = self.buffer("difference", (4, batch, sampled))
        np.take(self.background, index, out=difference, mode="clip")
        np.subtract(seen, difference, out=difference)
        difference *= weight
        view = self.buffer("view", (batch, sampled))
        np.sum(difference, axis=0, out=view)
        if self.radius:  # the blur spreads the sampled window to the whole one
            width = 2 * self.half_sampled + 1
            view = self._blur("window", view.reshape(batch, width, width), self.taps, grow=True).reshape(batch, m)
        view *= self.gain
        # Window pixels off the image (or of a marble that is not drawn) go to the spare last pixel.
        inside = (rows >= 0) & (rows < size) & (cols >= 0) & (cols < size) & finite[:, None]
        np.multiply(rows, size, out=rows)  # rows, cols are not needed any more
        rows += cols
        target = self.buffer("target", (batch, m), np.intp)
        np.copyto(target, rows, casting="unsafe")
        target += self._frame_offsets
        target[~inside] = batch * size * size
        image[target] += view  # distinct pixels but the spare one, which is discarded

    def _blur(self, name: str, image: np.ndarray, taps: np.ndarray, *, grow: bool) -> np.ndarray:
        """Separable Gaussian blur of (b, H, W) float32 images, each with its own symmetric taps
        ((b, radius + 1), centre first). ``grow=False``: the same size, the edge repeating beyond the
        border; ``grow=True``: zero beyond the border, the result ``radius`` larger on every side
        (all of it)."""
        r = self.radius
        g = r if grow else 0
        out = image
        for axis in range(2):  # along axis 1, then (transposed) along axis 2
            b, length, width = out.shape
            size = length + 2 * g
            padded = self.buffer(f"{name}pad{axis}", (b, size + 2 * r, width))
            padded[:, g + r : g + r + length] = out
            padded[:, : g + r] = 0.0 if grow else out[:, :1]
            padded[:, g + r + length :] = 0.0 if grow else out[:, -1:]
            result = self.buffer(f"{name}blur{axis}", (b, size, width))
            pair = self.buffer(f"{name}pair{axis}", (b, size, width))
            np.multiply(padded[:, r : r + size], taps[:, 0, None, None], out=result)
            for j in range(1, r + 1):
                np.add(padded[:, r - j : r - j + size], padded[:, r + j : r + j + size], out=pair)
                pair *= taps[:, j, None, None]
                result += pair
            out = result.transpose(0, 2, 1)
        return np.ascontiguousarray(out)


def _gaussian_kernel(sigma: float, radius: int) -> np.ndarray:
    """Normalised Gaussian taps ``-radius..radius`` (a unit impulse for sigma 0)."""
    offsets = np.arange(-radius, radius + 1, dtype=np.float64)
    if sigma <= 0:
        return (offsets == 0).astype(np.float32)
    taps = np.exp(-0.5 * (offsets / sigma) ** 2)
    return (taps / taps.sum()).astype(np.float32)
