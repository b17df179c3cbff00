"""The scene, in numpy: frame conventions, camera paths, meshes and their symmetries, specs,
occlusion. No shard I/O, no renderer."""
