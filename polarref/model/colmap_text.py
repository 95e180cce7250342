"""Checks of COLMAP text models before pycolmap reads them, and of names before they are written.

pycolmap's text reader stops at its first problem with a C++ assertion (``Check failed:
line_stream >> ...``) that names neither the file nor the line, and it reads an image name only
up to the first space, so "my photo 0000.png" comes back as "my" without complaint. COLMAP's
text format has no quoting: a name holding whitespace cannot be written to it at all. These
checks turn both into one line naming the file, the line and what to do.
"""

from __future__ import annotations

import math
from pathlib import Path

from polarref.core.errors import PolarrefError

# Parameters per camera model, as COLMAP's models.h defines them (pycolmap refuses other counts).
COLMAP_PARAM_COUNTS = {
    "SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8,
    "OPENCV_FISHEYE": 8, "FULL_OPENCV": 12, "FOV": 5, "SIMPLE_RADIAL_FISHEYE": 4,
    "RADIAL_FISHEYE": 5, "THIN_PRISM_FISHEYE": 12, "RAD_TAN_THIN_PRISM_FISHEYE": 16,
    "SIMPLE_FISHEYE": 3, "FISHEYE": 4,
}
TEXT_FILES = ("cameras.txt", "images.txt", "points3D.txt")


def names_text_cannot_hold(names) -> list[str]:
    """The names COLMAP's text format would cut at their first whitespace (or lose entirely)."""
    return [n for n in names if not n or any(ch.isspace() for ch in n)]


def refuse_names_for_text(names, where: str) -> None:
    """PolarrefError when any name cannot be written to COLMAP text (``where``: the output)."""
    bad = names_text_cannot_hold(names)
    if bad:
        raise PolarrefError(f"{where}: {len(bad)} image name(s), e.g. {bad[0]!r}, hold whitespace, which COLMAP's text "
                            "format cannot hold (COLMAP reads only up to the first space); write the "
                            "binary model or rename the images")


class _Lines:
    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise PolarrefError(f"{path}: not a UTF-8 text file (a COLMAP text model is plain text)") from None
        self.rows = [(i + 1, ln) for i, ln in enumerate(text.splitlines())
                     if ln.strip() and not ln.lstrip().startswith("#")]

    def fail(self, line: int, what: str) -> PolarrefError:
        return PolarrefError(f"{self.path}:{line}: {what}")

    def numbers(self, line: int, tokens: list[str], what: str, integer: bool = False) -> list[float]:
        out = []
        for tok in tokens:
            try:
                value = int(tok) if integer else float(tok)
            except ValueError:
                raise self.fail(line, f"{what}: expected {'an integer' if integer else 'a number'}, "
                                      f"got {tok!r}") from None
            if not math.isfinite(value):
                raise self.fail(line, f"{what}: non-finite value {tok!r}")
            out.append(value)
        return out


def check_text_model(folder: Path) -> None:
    """PolarrefError naming file and line for the first malformed line of a COLMAP text model."""
    _check_cameras(_Lines(folder / "cameras.txt"))
    _check_images(_Lines(folder / "images.txt"))
    if (folder / "points3D.txt").is_file():
        _check_points(_Lines(folder / "points3D.txt"))


def _check_cameras(f: _Lines) -> None:
    for line, text in f.rows:
        tok = text.split()
        if len(tok) < 4:
            raise f.fail(line, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        f.numbers(line, tok[:1] + tok[2:4], "camera id / width / height", integer=True)
        count = COLMAP_PARAM_COUNTS.get(tok[1])
        if count is None:
            raise f.fail(line, f"unknown camera model {tok[1]!r}")
        if len(tok) - 4 != count:
            raise f.fail(line, f"{tok[1]} takes {count} parameters, got {len(tok) - 4}")
        f.numbers(line, tok[4:], "camera parameters")


def _check_images(f: _Lines) -> None:
    # As COLMAP reads it: an image line (blank and comment lines before it skipped), then the
    # very next line, whatever it holds, as that image's points.
    raw = f.path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(raw):
        text = raw[i].strip()
        i += 1
        if not text or text.startswith("#"):
            continue
        _check_image_line(f, i, text)
        if i < len(raw):
            _check_points2d(f, i + 1, raw[i].split())
            i += 1


def _check_image_line(f: _Lines, line: int, text: str) -> None:
    tok = text.split()
    if len(tok) < 10:
        raise f.fail(line, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
    if len(tok) > 10:
        name = text.split(None, 9)[9]
        raise f.fail(line, f"image name {name!r} holds whitespace, which COLMAP's text format cannot "
                           f"hold (COLMAP would read {tok[9]!r}); use the binary model or rename the image")
    f.numbers(line, tok[:1] + tok[8:9], "image id / camera id", integer=True)
    f.numbers(line, tok[1:8], "pose")


def _check_points2d(f: _Lines, line: int, pts: list[str]) -> None:
    if len(pts) % 3:
        raise f.fail(line, "expected POINTS2D[] as (X, Y, POINT3D_ID) triples")
    f.numbers(line, [t for k, t in enumerate(pts) if k % 3 < 2], "keypoint")
    f.numbers(line, pts[2::3], "point id", integer=True)


def _check_points(f: _Lines) -> None:
    for line, text in f.rows:
        tok = text.split()
        if len(tok) < 8 or (len(tok) - 8) % 2:
            raise f.fail(line, "expected POINT3D_ID X Y Z R G B ERROR TRACK[] as (IMAGE_ID, POINT2D_IDX) pairs")
        f.numbers(line, tok[:1], "point id", integer=True)
        f.numbers(line, tok[1:4] + tok[7:8], "position / error")
        rgb = f.numbers(line, tok[4:7], "colour", integer=True)
        if not all(0 <= c <= 255 for c in rgb):
            raise f.fail(line, f"colour {tok[4:7]} outside 0..255")
        f.numbers(line, tok[8:], "track", integer=True)
