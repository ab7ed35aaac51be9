"""The ``pipeline`` command: starts and supervises the node graph, replays bags into it, records it."""
