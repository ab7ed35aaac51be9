"""What every node process runs on: the node base, executor, memory, DDS and shutdown support."""
