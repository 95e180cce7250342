"""Real photo sets of the SfM evaluation (issue 32): where each comes from, where it is kept.

The photos never enter the repository. ``python -m polarref.io.photo_sets get`` copies each set,
unchanged (EXIF kept), out of a git clone of its public GitHub repository at a pinned commit into
``<root>/<name>/images/``; ``<root>`` is ``$POLARREF_PHOTO_SETS`` or ``cache_root()/photo-sets``.
``--git-dirs DIR`` reads existing clones ``DIR/<owner>+<name>/repo`` (bare or not) instead of
cloning. The Strecha fountain comes from the reference data (``$POLARREF_DATA``) with its
ground truth. Sources and licences: docs/photo-sets.md.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from polarref.core.data import cache_root, data_root

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


@dataclass(frozen=True)
class PhotoSet:
    """One public photo set."""

    name: str
    repo: str        # GitHub owner/name ("" = the reference data)
    commit: str      # the commit the photos are read at
    folder: str      # folder of the photos inside the repository
    licence: str
    what: str


FOUNTAIN = PhotoSet("fountain", "", "", "strecha_fountain-P11/images",
                    "Strecha et al. CVPR 2008 (EPFL), research use; via the reference data",
                    "11 photos 3072x2048, one camera, no EXIF, ground-truth cameras")
PHOTO_SETS: tuple[PhotoSet, ...] = (
    FOUNTAIN,
    PhotoSet("sceaux", "openMVG/ImageDataset_SceauxCastle", "fde7f5faba555e3c54700477c304488613346a19", "images",
             "copyright 2012 Pierre Moulon, published as openMVG's SfM sample (no licence file)",
             "11 photos of a castle, one camera (Kodak, 2832x2128), EXIF focal"),
    PhotoSet("sacre_coeur", "cvg/Hierarchical-Localization", "c13273bd0ecc2917a35910fd843712a1c6243193",
             "datasets/sacre_coeur/mapping",
             "repository Apache-2.0; photos from YFCC100M (Flickr, Creative Commons) via IMC 2021",
             "10 internet photos of one landmark, 10 cameras and sizes, no EXIF focal"),
    PhotoSet("lund", "mapillary/OpenSfM", "238744cdf3b5d50149c50d136a87f7fea25ad5cd", "data/lund/images",
             "repository BSD-2-Clause (OpenSfM test data)",
             "29 photos around a building (Lund cathedral), one camera, EXIF"),
    PhotoSet("berlin", "mapillary/OpenSfM", "238744cdf3b5d50149c50d136a87f7fea25ad5cd", "data/berlin/images",
             "repository BSD-2-Clause (OpenSfM test data)",
             "3 street photos, one camera, EXIF with GPS"),
)
BY_NAME = {s.name: s for s in PHOTO_SETS}


def photo_sets_root() -> Path:
    env = os.environ.get("POLARREF_PHOTO_SETS")
    return Path(env).expanduser() if env else cache_root() / "photo-sets"


def image_dir(name: str) -> Path | None:
    """The folder of a set's photos on this machine, or None when it is not laid out."""
    s = BY_NAME[name]
    if not s.repo:
        root = data_root()
        d = root / s.folder if root is not None else None
    else:
        d = photo_sets_root() / name / "images"
    return d if d is not None and d.is_dir() and any(d.iterdir()) else None


def gt_dir(name: str) -> Path | None:
    """Folder of Strecha ``*.camera`` ground truth of a set, or None (only the fountain has one)."""
    d = image_dir(name)
    if d is None or BY_NAME[name].repo:
        return None
    g = d.parent / "gt_dense_cameras"
    return g if g.is_dir() else None


def _git(git_dir: Path, *args: str, text: bool = True):
    return subprocess.run(["git", "--git-dir", str(git_dir), *args], check=True, capture_output=True,
                          text=text).stdout


def _git_dir(s: PhotoSet, git_dirs: Path | None) -> Path:
    """A git directory holding ``s.commit``: an existing clone under ``git_dirs`` or a new one."""
    if git_dirs is not None:
        base = git_dirs / s.repo.replace("/", "+")
        for cand in (base / "repo", base / "repo" / ".git", base, base / ".git"):
            if (cand / "HEAD").is_file():
                return cand
        raise FileNotFoundError(f"no clone of {s.repo} under {git_dirs}")
    dst = photo_sets_root() / ".clones" / s.repo.replace("/", "+")
    if not dst.is_dir():
        subprocess.run(["git", "clone", "--bare", "--filter=blob:none", f"https://github.com/{s.repo}", str(dst)],
                       check=True)
    return dst


def lay_out(s: PhotoSet, git_dirs: Path | None = None) -> Path:
    """Write ``<root>/<name>/images/`` (files already there are kept); returns that folder."""
    git = _git_dir(s, git_dirs)
    rev = s.commit if _has(git, s.commit) else "HEAD"
    names = _git(git, "ls-tree", "--name-only", rev, s.folder + "/").split()
    out = photo_sets_root() / s.name / "images"
    out.mkdir(parents=True, exist_ok=True)
    for path in names:
        if not path.lower().endswith(IMAGE_SUFFIXES):
            continue
        dst = out / Path(path).name
        if dst.exists():
            continue
        tmp = dst.with_name("." + dst.name + ".tmp")
        tmp.write_bytes(_git(git, "show", f"{rev}:{path}", text=False))
        tmp.replace(dst)
    (out.parent / "SOURCE.txt").write_text(
        f"{s.what}\nsource: https://github.com/{s.repo} {s.folder} at {_git(git, 'rev-parse', rev).strip()}\n"
        f"licence: {s.licence}\n")
    return out


def _has(git: Path, commit: str) -> bool:
    return subprocess.run(["git", "--git-dir", str(git), "cat-file", "-e", f"{commit}^{{commit}}"],
                          capture_output=True).returncode == 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m polarref.io.photo_sets", description=__doc__.splitlines()[0])
    p.add_argument("action", choices=("get", "list"))
    p.add_argument("names", nargs="*", help=f"sets (default: all): {', '.join(BY_NAME)}")
    p.add_argument("--git-dirs", type=Path, help="folder of existing clones <owner>+<name>/repo")
    args = p.parse_args(argv)
    unknown = [n for n in args.names if n not in BY_NAME]
    if unknown:
        p.error(f"unknown photo set {unknown[0]!r}; choose from {', '.join(BY_NAME)}")
    for s in PHOTO_SETS:
        if args.names and s.name not in args.names:
            continue
        if args.action == "list" or not s.repo:
            print(f"{s.name}: {s.repo or 'reference data'} {s.folder} ({s.licence}) -> "
                  f"{image_dir(s.name) or 'absent'}")
            continue
        try:
            print(f"{s.name}: {lay_out(s, args.git_dirs)}")
        except (subprocess.CalledProcessError, OSError) as exc:
            detail = exc.stderr.strip().splitlines()[-1] if getattr(exc, "stderr", None) else str(exc)
            print(f"polarref photo_sets: {s.name}: {detail}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
