"""Public real photo collections for the SfM evaluation: where each comes from, where it is kept.

The images never enter the repository. ``python -m polarref.collections get`` copies each set
out of a local mirror of its public GitHub repository (or a clone of it), downscales every
photo so its longer side is at most :data:`MAX_SIDE` px (EXIF kept, so EXIF focal lengths stay
valid: they are stored relative to the sensor, not in pixels), and writes
``<root>/<name>/images/``. ``<root>`` is ``$POLARREF_COLLECTIONS`` or
``polarref.core.data.cache_root() / "collections"``.
"""

from __future__ import annotations

import argparse
import logging
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from polarref.core.data import cache_root, data_root

log = logging.getLogger(__name__)

MAX_SIDE = 1600  # px: every run of the evaluation takes minutes on 2 cores at this size


@dataclass(frozen=True)
class Collection:
    """One public photo set."""

    name: str
    repo: str              # GitHub owner/name
    folder: str            # folder of the images inside the repository
    licence: str
    what: str


COLLECTIONS: tuple[Collection, ...] = (
    Collection("sceaux", "openMVG/ImageDataset_SceauxCastle", "images",
               "copyright 2012 Pierre Moulon, published as openMVG's SfM sample (no licence file)",
               "11 photos of one castle, one camera (Kodak, 2832x2128), EXIF focal"),
    Collection("sacre_coeur", "cvg/Hierarchical-Localization", "datasets/sacre_coeur/mapping",
               "repository Apache-2.0; photos from YFCC100M (Flickr, Creative Commons) via IMC 2021",
               "10 internet photos of one landmark, 10 cameras and sizes"),
    Collection("lund", "mapillary/OpenSfM", "data/lund/images",
               "repository BSD-2-Clause (OpenSfM test data)",
               "29 photos walking around a building (Lund cathedral), one camera"),
    Collection("berlin", "mapillary/OpenSfM", "data/berlin/images",
               "repository BSD-2-Clause (OpenSfM test data)",
               "3 street photos, one camera, EXIF with GPS"),
)


def collections_root() -> Path:
    env = os.environ.get("POLARREF_COLLECTIONS")
    return Path(env).expanduser() if env else cache_root() / "collections"


def image_dir(name: str) -> Path | None:
    """``images/`` of a collection on this machine, or None when it was not fetched.

    ``fountain`` is the Strecha set in the reference data (``$POLARREF_DATA``).
    """
    if name == "fountain":
        root = data_root()
        d = root / "strecha_fountain-P11" if root else None
        return d if d is not None and (d / "images").is_dir() else None
    d = collections_root() / name
    return d if (d / "images").is_dir() and any((d / "images").iterdir()) else None


def _mirror(repo: str) -> Path:
    """Git directory of a local mirror (``$POLARREF_MIRRORS``/owner+name/repo) or a fresh shallow clone."""
    base = Path(os.environ.get("POLARREF_MIRRORS", "/work/.mirror"))
    m = base / repo.replace("/", "+") / "repo"
    if m.is_dir():
        return m
    dst = collections_root() / ".clones" / repo.replace("/", "+")
    if not dst.is_dir():
        subprocess.run(["git", "clone", "--bare", "--depth", "1", f"https://github.com/{repo}", str(dst)],
                       check=True)
    return dst


def _downscaled(data: bytes, max_side: int) -> bytes:
    import io

    from PIL import Image

    with Image.open(io.BytesIO(data)) as im:
        exif = im.info.get("exif")
        w, h = im.size
        if max(w, h) <= max_side:
            return data
        s = max_side / max(w, h)
        small = im.convert("RGB").resize((round(w * s), round(h * s)), Image.Resampling.LANCZOS)
        buf = io.BytesIO()
        small.save(buf, "JPEG", quality=95, **({"exif": exif} if exif else {}))
        return buf.getvalue()


def fetch(c: Collection, max_side: int = MAX_SIDE) -> Path:
    """Write ``<root>/<c.name>/images/`` (skipping files already there); returns the set's folder."""
    git = _mirror(c.repo)
    names = subprocess.run(["git", "--git-dir", str(git), "ls-tree", "--name-only", "HEAD", c.folder + "/"],
                           check=True, capture_output=True, text=True).stdout.split()
    out = collections_root() / c.name / "images"
    out.mkdir(parents=True, exist_ok=True)
    for path in names:
        if not path.lower().endswith((".jpg", ".jpeg", ".png")):
            continue
        dst = out / Path(path).name
        if dst.exists():
            continue
        blob = subprocess.run(["git", "--git-dir", str(git), "show", f"HEAD:{path}"], check=True,
                              capture_output=True).stdout
        tmp = dst.with_name("." + dst.name + ".tmp")
        tmp.write_bytes(_downscaled(blob, max_side))
        tmp.replace(dst)
    return out.parent


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m polarref.collections", description=__doc__.splitlines()[0])
    p.add_argument("action", choices=("get", "list"))
    p.add_argument("names", nargs="*", help="collections (default: all)")
    args = p.parse_args(argv)
    wanted = [c for c in COLLECTIONS if not args.names or c.name in args.names]
    for c in wanted:
        if args.action == "get":
            try:
                print(f"{c.name}: {fetch(c)}")
            except (subprocess.CalledProcessError, OSError) as exc:
                print(f"polarref collections: {c.name}: {exc}", file=sys.stderr)
                return 1
        else:
            print(f"{c.name}: {c.repo}:{c.folder} ({c.licence}) -> {image_dir(c.name) or 'not fetched'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
