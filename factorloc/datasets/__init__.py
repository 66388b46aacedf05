"""The on-disk scenario format and loaders for public datasets."""
