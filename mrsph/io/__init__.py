"""Input and output: snapshots, frame dumps, the water surface."""
