"""The graph's nodes, one module each (listed in :data:`gldt_ros.interface.graph.NODES`); each exposes
``create_node(cli_args)`` and ``main()``."""
