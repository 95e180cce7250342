"""The front-end cache's checksummed entries: the sidecar is the file's SHA-256, computed without
holding the file in memory, and a changed entry is detected and removed."""

import hashlib
import tracemalloc

import numpy as np

from polarref.sfm import cache


def _entry(tmp_path, n_bytes: int):
    path = tmp_path / "features-x.npz"
    path.write_bytes(np.random.default_rng(7).bytes(n_bytes))
    return path


def test_seal_writes_the_files_sha256(tmp_path):
    path = _entry(tmp_path, 3 * 2**20 + 17)  # several read chunks and a ragged tail
    cache.seal(path)
    side = path.with_name(path.name + ".sha256").read_text().strip()
    assert side == hashlib.sha256(path.read_bytes()).hexdigest()
    assert cache.cache_valid(path)


def test_checksum_does_not_hold_the_entry_in_memory(tmp_path):
    path = _entry(tmp_path, 24 * 2**20)
    tracemalloc.start()
    try:
        cache.seal(path)
        assert cache.cache_valid(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # reading the entry whole allocated its 24 MiB (twice: seal and check)
    assert peak < 2 * 2**20


def test_a_changed_entry_is_invalid_and_removed(tmp_path):
    path = _entry(tmp_path, 2**20)
    cache.seal(path)
    with open(path, "r+b") as fh:
        fh.seek(2**19)
        byte = fh.read(1)
        fh.seek(2**19)
        fh.write(bytes([byte[0] ^ 1]))
    assert not cache.cache_valid(path)
    assert not path.exists() and not path.with_name(path.name + ".sha256").exists()
