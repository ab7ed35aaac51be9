"""What the nodes and their users agree on: topics, QoS, parameters, messages, links, the graph."""
