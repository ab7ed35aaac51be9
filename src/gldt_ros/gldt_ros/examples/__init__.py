"""Example users of the graph's outputs."""
