"""spm_data.io.shards.seal: the header naming a shard's SHA-256, and the check every open runs."""

import hashlib

import pytest

from spm_data.io.shards.seal import (HDF5_SIGNATURE, MAGIC, USERBLOCK, SealError, check, content_digest, header, seal,
                                     stored_digest, verified_digest)


def test_a_sealed_file_names_the_sha256_of_what_follows_its_header(tmp_path):
    path = tmp_path / "f"
    body = b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 10
    path.write_bytes(b"\0" * USERBLOCK + body)
    digest = seal(path)
    assert digest == hashlib.sha256(body).hexdigest() == content_digest(path) == verified_digest(path)
    assert path.read_bytes()[:USERBLOCK] == header(digest) == MAGIC + digest.encode() + b"\n" + b"\0" * (
        USERBLOCK - len(MAGIC) - 65)


@pytest.mark.parametrize("block, reason", [
    (HDF5_SIGNATURE + b"\0" * 504, "without spm's whole-file checksum"),
    (b"PK\3\4" + b"\0" * 508, "not an spm shard: it does not start with spm's header"),
    (b"", "not an spm shard"),
    (MAGIC + b"z" * 64 + b"\n" + b"\0" * 430, r"checksum header \(the first 512 bytes\) is damaged"),
    (header("ab" * 32)[:-1] + b"\1", r"checksum header \(the first 512 bytes\) is damaged"),
])
def test_a_header_that_is_not_spms_is_refused_with_why(block, reason):
    with pytest.raises(SealError, match=reason) as info:
        stored_digest(block)
    assert not info.value.mismatch


def test_check_compares_the_content_with_the_header():
    assert check(header("ab" * 32), lambda: "ab" * 32) == "ab" * 32
    with pytest.raises(SealError, match="differ from the SHA-256 it was written with") as info:
        check(header("ab" * 32), lambda: "cd" * 32)
    assert info.value.mismatch


def test_a_verification_handed_to_another_process_holds_while_the_file_is_unchanged(tmp_path, monkeypatch):
    """verification(path) in the parent, reuse_verification in a worker: the worker does not hash
    the file again, unless it changed since (then it hashes, and finds the change)."""
    import spm_data.io.shards.seal as seal_module
    from spm_data.io.shards.seal import forget, reuse_verification, verification

    path = tmp_path / "f"
    path.write_bytes(b"\0" * USERBLOCK + b"\x89HDF\r\n\x1a\n" + bytes(1000))
    seal(path)
    monkeypatch.setattr(seal_module, "RACY_SECONDS", -1.0)  # remembered at once (not racily clean)
    forget()
    digest = verified_digest(path)
    known = verification(path)
    assert known is not None and known[1] == digest
    forget()  # a fresh process
    hashed = []
    monkeypatch.setattr(seal_module, "content_digest", lambda p: hashed.append(p) or content_digest(p))
    reuse_verification(path, known)
    assert verified_digest(path) == digest and hashed == []
    forget()
    with open(path, "r+b") as fh:  # a changed byte: its stat changes, the handed check does not apply
        fh.seek(USERBLOCK + 20)
        fh.write(b"\1")
    reuse_verification(path, known)
    with pytest.raises(SealError, match="differ from the SHA-256"):
        verified_digest(path)
    assert hashed == [path]
    reuse_verification(path, None)  # nothing handed: nothing changes
    reuse_verification(tmp_path / "gone", known)  # a file gone since: the open that follows says so


def test_hash_ahead_leaves_each_open_its_check_done_and_failures_to_the_open(tmp_path, monkeypatch):
    import spm_data.io.shards.seal as seal_module
    from spm_data.io.shards.seal import forget, hash_ahead

    monkeypatch.setattr(seal_module, "RACY_SECONDS", -1.0)
    paths = []
    for k in range(3):
        path = tmp_path / f"f{k}"
        path.write_bytes(b"\0" * USERBLOCK + b"\x89HDF\r\n\x1a\n" + bytes([k]) * 5000)
        seal(path)
        paths.append(path)
    (tmp_path / "bad").write_bytes(b"not a shard")
    forget()
    hash_ahead(paths + [tmp_path / "bad", tmp_path / "gone"])  # the bad and the missing: no error here
    hashed = []
    real = seal_module.content_digest
    monkeypatch.setattr(seal_module, "content_digest", lambda p: hashed.append(p) or real(p))
    assert [verified_digest(p) for p in paths] == [content_digest(p) for p in paths]
    assert hashed == []  # every open found its check done
    with pytest.raises(SealError, match="not an spm shard"):
        verified_digest(tmp_path / "bad")


def test_seal_flushes_the_file_and_says_when_the_disk_fails(tmp_path, monkeypatch):
    import os

    path = tmp_path / "f"
    path.write_bytes(b"\0" * USERBLOCK + b"\x89HDF\r\n\x1a\n" + bytes(100))
    synced = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd) or real(fd))
    digest = seal(path)
    assert len(synced) == 2 and digest == content_digest(path)  # the content while hashed, then the header

    def failing(fd):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "fsync", failing)
    with pytest.raises(OSError, match="Input/output error"):
        seal(path)
