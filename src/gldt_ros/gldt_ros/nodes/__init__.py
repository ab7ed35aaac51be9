"""One module per node; each exposes ``create_node(cli_args)`` and ``main()``."""
