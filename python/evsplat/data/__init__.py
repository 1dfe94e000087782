"""Data in and out: event streams and their file formats (poses, images and the simulator join
them here)."""
