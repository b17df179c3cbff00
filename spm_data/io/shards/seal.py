"""A shard is trusted only whole: the SHA-256 of its bytes, in its first 512 bytes.

A shard's HDF5 data starts at byte 512 (an HDF5 *user block*, which HDF5 skips);
the user block holds one line, ``spm-shard sha256=<64 hex digits>``, then zeros.
The digest covers every byte after the user block, so a change to any byte of the
file (data, HDF5 metadata, or the header itself) is found before HDF5 reads
anything: the Fletcher-32 and CRC-32 checks (checksums.py) name the part that
changed, but they cover neither HDF5's own metadata nor a chunk's filter mask.

``verified_digest`` streams the file once (about 1 GB/s); a file already verified
in this process and not changed since (same device, inode, size, mtime and ctime,
its ctime at least RACY_SECONDS old when verified, as git treats a racily clean
index) is not hashed again.
"""

from __future__ import annotations

import hashlib
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

USERBLOCK = 512
MAGIC = b"spm-shard sha256="
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
RACY_SECONDS = 2.0
_BLOCK = 1 << 20

_verified: dict[str, tuple] = {}  # absolute path -> (stat key, digest) of files verified by this process


class SealError(Exception):
    """Why a file's bytes cannot be trusted (the caller names the file; reader.open_h5)."""

    def __init__(self, reason: str, mismatch: bool = False):
        super().__init__(reason)
        self.mismatch = mismatch  # True: the header is whole and the bytes after it differ from it


def content_digest(path) -> str:
    """The hex SHA-256 of the bytes of ``path`` after its user block."""
    h = hashlib.sha256()
    buf = bytearray(_BLOCK)
    view = memoryview(buf)
    with open(path, "rb") as fh:
        fh.seek(USERBLOCK)
        while n := fh.readinto(buf):
            h.update(view[:n])
    return h.hexdigest()


def header(digest: str) -> bytes:
    """The user block for a file whose content digest is ``digest`` (64 hex digits)."""
    return _header(digest.encode("ascii"))


def _header(digest: bytes) -> bytes:
    line = MAGIC + digest + b"\n"
    return line + b"\0" * (USERBLOCK - len(line))


def seal(path) -> str:
    """Write the header of a finished shard (its HDF5 file closed) and return the digest,
    once every byte of the file is on disk (fsync): the content is flushed on another
    thread while it is hashed, then the header."""
    with open(path, "r+b") as fh, ThreadPoolExecutor(max_workers=1) as pool:
        flushed = pool.submit(os.fsync, fh.fileno())
        try:
            digest = content_digest(path)
        finally:
            flushed.result()  # its error (a failing disk) is the caller's, as the hash's is
        fh.write(header(digest))
        fh.flush()
        os.fsync(fh.fileno())
    return digest


def stored_digest(block: bytes) -> str:
    """The digest a user block names; SealError when it is not a well-formed spm header."""
    if block.startswith(HDF5_SIGNATURE):
        raise SealError("an HDF5 file without spm's whole-file checksum (a shard of schema version 2 or "
                        "earlier, or not an spm shard), so it cannot be verified; make it again with this spm "
                        "(render, import or occlude into a new --out)")
    if not block.startswith(MAGIC[:4]):
        raise SealError("not an spm shard: it does not start with spm's header (a foreign file, or a damaged one)")
    digest = block[len(MAGIC):len(MAGIC) + 64]
    if block != _header(digest) or len(digest) != 64 or digest.strip(b"0123456789abcdef"):
        raise SealError("its checksum header (the first 512 bytes) is damaged; the shard is corrupt")
    return digest.decode("ascii")


def check(block: bytes, digest_of_content) -> str:
    """The digest of a file whose first USERBLOCK bytes are ``block`` and whose content
    hashes to ``digest_of_content()`` (called only for a well-formed header), when the two
    agree; SealError otherwise."""
    digest = stored_digest(block)
    if digest_of_content() != digest:
        raise SealError("its bytes differ from the SHA-256 it was written with (a changed or flipped byte)",
                        mismatch=True)
    return digest


def _stat_key(st: os.stat_result) -> tuple:
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


def verified_digest(path) -> str:
    """The content digest of ``path`` after checking every byte against its header;
    SealError (its reason, without the path) when they differ or there is no header.
    OSError when the file cannot be read."""
    key = os.path.abspath(path)
    st = os.stat(path)
    known = _verified.get(key)
    if known is not None and known[0] == _stat_key(st):
        return known[1]
    with open(path, "rb") as fh:
        block = fh.read(USERBLOCK)
    digest = check(block, lambda: content_digest(path))
    if time.time() - st.st_ctime > RACY_SECONDS and _stat_key(os.stat(path)) == _stat_key(st):
        _verified[key] = (_stat_key(st), digest)
    return digest


def hash_ahead(paths, threads: int = 2) -> None:
    """verified_digest of each file on ``threads`` threads (hashlib releases the GIL), ahead of
    the opens that then find the check done while a file is unchanged (a file changed within
    RACY_SECONDS is hashed again). What fails is left to the open, which says it."""
    def digest(path):
        try:
            verified_digest(path)
        except (SealError, OSError):
            pass

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(digest, paths))


def verification(path) -> tuple | None:
    """What this process knows of ``path`` verified, ``(stat key, digest)``, or None; for a worker
    process (reuse_verification), so the file is not hashed again there."""
    return _verified.get(os.path.abspath(path))


def reuse_verification(path, known: tuple | None) -> None:
    """Take ``known`` (verification(path) in another process of this run) as this process's own
    check of ``path`` when the file's device, inode, size, mtime and ctime are still those it
    was verified with (verified_digest's own rule); otherwise nothing: the next open hashes."""
    try:
        if known is not None and _stat_key(os.stat(path)) == tuple(known[0]):
            _verified[os.path.abspath(path)] = (tuple(known[0]), known[1])
    except OSError:
        pass  # gone or unreadable: the open that follows says so


def forget(path=None) -> None:
    """Drop what this process knows verified (one path, or all): the next open hashes again."""
    if path is None:
        _verified.clear()
    else:
        _verified.pop(os.path.abspath(Path(path)), None)
