"""The scene, in numpy: frame conventions, camera paths, meshes and their symmetries, specs, occlusion. No I/O of shards, no renderer."""
