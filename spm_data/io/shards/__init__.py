"""HDF5 shards: the one place they are read and written (docs/shard-format.md).

``schema`` (fields, dtypes, shapes), ``seal`` (a shard's SHA-256 in its header,
checked on every open), ``reader`` (every read verified),
``writer`` (streamed, checksummed, atomic), ``chunks`` (image frames encoded and
decoded as HDF5's filters store them, on threads; compressed ahead while the renderer
draws), ``manifest`` (a folder's shards and
``manifest.json``), ``identity`` (no frame read twice, from the shards' bytes), ``checksums`` (Fletcher-32 as HDF5
computes it, CRC-32 of
attributes and layouts). Nothing else in spm opens an HDF5 file; import from here.
"""

from spm_data.io.shards.manifest import (list_shards, listed_twice, manifest_entry, no_shards, read_manifest,
                                         remove_partials, write_manifest)
from spm_data.io.shards.reader import (H5_ERRORS, ShardReader, forget_checks, h5_is_string, read_attrs, read_shard,
                                       shard_digest, shard_layout, verify_shard)
from spm_data.io.shards.schema import (FIELDS, IMAGE_FIELDS, MANIFEST, MAY_BE_ABSENT, MISSING, OPTIONAL_FIELDS,
                                       REQUIRED_ATTRS, SCHEMA_VERSION, SHARD_SUFFIX, SIZED_FIELDS, SOURCES,
                                       check_arrays)
from spm_data.io.shards.seal import hash_ahead, reuse_verification, verification
from spm_data.io.shards.chunks import encode_chunk
from spm_data.io.shards.writer import ShardWriter, write_shard

__all__ = ["FIELDS", "H5_ERRORS", "IMAGE_FIELDS", "MANIFEST", "MAY_BE_ABSENT", "MISSING", "OPTIONAL_FIELDS",
           "REQUIRED_ATTRS", "SCHEMA_VERSION", "SHARD_SUFFIX", "SIZED_FIELDS", "SOURCES", "ShardReader", "ShardWriter",
           "check_arrays",
           "encode_chunk", "forget_checks", "h5_is_string", "hash_ahead", "list_shards", "listed_twice",
           "manifest_entry", "no_shards", "read_attrs", "read_manifest", "read_shard", "remove_partials",
           "reuse_verification", "shard_digest", "shard_layout", "verification", "verify_shard", "write_manifest",
           "write_shard"]
