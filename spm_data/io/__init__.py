"""Storage: shards (the one reader and writer), folders by manifest, locks, atomic files,
images, training-loop datasets."""
